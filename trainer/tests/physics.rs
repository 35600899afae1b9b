//! The physics estimator on generated robots: its map, trained on robots drawn from the generator and paired with
//! the excitation of a few simulated recordings, names what the torques identify exactly on robots it never saw.

#[path = "../../dataset/tests/common/mod.rs"]
mod common;

use std::collections::BTreeMap;
use std::sync::atomic::AtomicBool;

use dynforge_dataset::cache::evidence::PhysicsSet;
use dynforge_dataset::evidence::{generator_prior, measured_evidence, recording_evidence};
use dynforge_dataset::examples::ExampleRecord;
use dynforge_dataset::examples::Examples;
use dynforge_dataset::examples::generated::{PhysicsExamples, PhysicsSource};
use dynforge_dataset::metrics::score;
use dynforge_dataset::split::{Split, SplitRule, split_of};
use dynforge_dataset::window::WindowSpec;
use dynforge_identify::{Evidence, PAIRED_NOISE_GAIN};
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::job::Job;
use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};
use dynforge_recording::read;
use dynforge_robot::generator::generate;
use dynforge_robot::parameters::{dynamic_parameters, labels_of};
use dynforge_trainer::checkpoint::{Checkpoint, PriorRecord};
use dynforge_trainer::inference::Predictor;
use dynforge_trainer::model::{NetworkConfig, PhysicsConfig};
use dynforge_trainer::training::{Run, TrainConfig, train};

/// The labels the torques of a rich motion fix exactly (the generator's structure leaves four directions of its 30
/// unseen, which touch link 1's mass and COM, the split of mass between links 4 and 5, and first moments of links
/// 2-3 against masses of links 4-5): friction, the masses of links 2, 3 and 6, every Izz, and link 6's COM and
/// moments.
fn exactly_identifiable(k: usize) -> bool {
    let l = &LABELS[k];
    match l.kind {
        LabelKind::Coulomb | LabelKind::Viscous | LabelKind::Izz => true,
        LabelKind::Mass => matches!(l.index, 2 | 3 | 6),
        LabelKind::Com | LabelKind::Ixx | LabelKind::Iyy => l.index == 6,
    }
}

#[test]
fn the_map_recovers_the_exactly_identifiable_labels_of_robots_it_never_saw() {
    let cfg = GeneratorConfig::default();
    let prior = generator_prior(&cfg, 41).unwrap();
    assert_eq!(prior.rank(), 30, "the generated arms span 30 of the 72 parameter directions");
    // The excitation: 3 robots x 6 trajectories, simulated.
    let shards = tempfile::tempdir().unwrap();
    let spec = WindowSpec::default();
    let mut set = PhysicsSet::new(spec, prior.rank());
    for robot in 0..3 {
        for trajectory in 0..6 {
            let (path, _) = common::write_shard(&Job { seed: 4, robot, trajectory }, shards.path());
            set.add(&read(&path, None).unwrap(), &prior).unwrap();
        }
    }
    // One validation robot of the three.
    let validation = |(s, f): (u64, f64), r: u64| split_of(s, r, f) == Split::Validation;
    let split = (0..100).map(|s| (s, 0.3)).find(|&sf| (0..3).filter(|&r| validation(sf, r)).count() == 1).unwrap();
    let record = ExampleRecord { generated_per_epoch: 16384, real: true, noisy: false };
    let source = PhysicsSource { generator: cfg.clone(), seed: 1234, examples: record };
    let mut examples = PhysicsExamples::new(&set, prior.clone(), &SplitRule::robots(split.0, split.1), source).unwrap();
    let model = PhysicsConfig { hidden: 128, layers: 2, ..PhysicsConfig::new(examples.shape()[1]) };
    let family = generate(&cfg, 4, 0).unwrap().model;
    let mut ck = Checkpoint::new(NetworkConfig::Physics(model), &spec, &family, None, examples.standardizer());
    ck.prior = Some(PriorRecord::new(&prior));
    let out = tempfile::tempdir().unwrap();
    let train_cfg =
        TrainConfig { epochs: 6, batch: 256, lr: 2e-3, micro_batches: 2, patience: 10, ..TrainConfig::default() };
    train(
        &mut examples,
        None,
        ck,
        &Run { dir: out.path(), config: &train_cfg, resume: false, stop: &AtomicBool::new(false) },
        &mut (),
    )
    .unwrap();

    // Fresh generated robots, never simulated nor trained on, seen through the excitation of a training robot's six
    // recordings (as training pairs generated robots with the training robots' excitations).
    let predictor = Predictor::load(out.path()).unwrap();
    let train_robot = (0..3).find(|&r| !validation(split, r)).unwrap();
    let mine: Vec<usize> = (0..set.recordings.len()).filter(|&i| set.recordings.robots[i] == train_robot).collect();
    let mut excitation = set.recordings.get(mine[0]);
    for &i in &mine[1..] {
        excitation.add(&set.recordings.get(i));
    }
    let (mut evidence, mut truth) = (Vec::new(), Vec::new());
    for id in 0..400 {
        let robot = generate(&cfg, 777, id).unwrap().model;
        let z = prior.coordinates(&dynamic_parameters(&robot));
        evidence.push(Evidence::noiseless(prior.rank(), &excitation.h, &z));
        truth.push(labels_of(&robot).unwrap());
    }
    let predicted = predictor.predict_evidence(&evidence).unwrap();
    let plug_in: Vec<[f64; NUM_LABELS]> = evidence
        .iter()
        .map(|e| dynforge_identify::labels_of_parameters(&prior.parameters(&e.posterior().unwrap().mean)))
        .collect();
    let p = score(&plug_in, &truth, &predictor.checkpoint.standardizer().label_std);
    let s = score(&predicted, &truth, &predictor.checkpoint.standardizer().label_std);
    let exact: Vec<usize> = (0..NUM_LABELS).filter(|&k| exactly_identifiable(k)).collect();
    assert_eq!(exact.len(), 24);
    for &k in &exact {
        assert!(s.targets[k].r2 > 0.99, "{}: R2 {:.4}", LABELS[k].name, s.targets[k].r2);
    }
    // The rest is what the generator's distribution implies, which the labels of the Gaussian posterior's mean
    // (the plug-in estimate the map starts from) miss: the map does better overall (measured 0.967 vs 0.948).
    assert!(s.r2 > p.r2 + 0.005 && s.r2 > 0.9, "overall R2 {:.4}, plug-in {:.4}", s.r2, p.r2);
}

/// `--generated-only`: the training examples are exactly the generated robots of the run that also trains on the
/// dataset's examples (same draws, same standardisation), and validation is unchanged. `--noisy`: the same robots
/// and labels, and about half of them (binomial, 48 draws: 24 +- 3.5) seen through noisy evidence.
#[test]
fn generated_only_and_noisy_examples_change_only_what_they_say() {
    let cfg = GeneratorConfig::default();
    let prior = generator_prior(&cfg, 41).unwrap();
    let shards = tempfile::tempdir().unwrap();
    let mut set = PhysicsSet::new(WindowSpec::default(), prior.rank());
    for robot in 0..2 {
        for trajectory in 0..2 {
            let (path, _) = common::write_shard(&Job { seed: 4, robot, trajectory }, shards.path());
            set.add(&read(&path, None).unwrap(), &prior).unwrap();
        }
    }
    let validation = |(s, f): (u64, f64), r: u64| split_of(s, r, f) == Split::Validation;
    let split = (0..100).map(|s| (s, 0.5)).find(|&sf| validation(sf, 0) != validation(sf, 1)).unwrap();
    let examples = |real: bool, noisy: bool| {
        let examples = ExampleRecord { generated_per_epoch: 48, real, noisy };
        let source = PhysicsSource { generator: cfg.clone(), seed: 99, examples };
        let mut e = PhysicsExamples::new(&set, prior.clone(), &SplitRule::robots(split.0, split.1), source).unwrap();
        e.begin_epoch(2);
        e
    };
    let (both, generated) = (examples(true, false), examples(false, false));
    let real = both.train_len() - generated.train_len();
    assert!(real > 0 && both.real() == real && generated.real() == 0, "{real} real examples");
    assert!(generated.train_len() > 40, "{} of 48 generated robots drawn", generated.train_len());
    for k in 0..generated.train_len() {
        assert_eq!(generated.train_batch(&[k]), both.train_batch(&[real + k]), "generated example {k}");
    }
    let validation = |e: &dyn Examples| (e.validation_inputs(0..e.validation_len()), e.validation_labels());
    assert_eq!(validation(&generated), validation(&both));

    // Un-standardised inputs, column -> value, to compare examples across the two runs' statistics.
    let raw = |e: &PhysicsExamples, k: usize| -> BTreeMap<usize, f64> {
        let s = e.standardizer();
        let x = e.train_batch(&[k]).0;
        s.columns.iter().enumerate().map(|(i, &c)| (c, x[i] as f64 * s.std[i] + s.mean[i])).collect()
    };
    let noisy = examples(false, true);
    assert_eq!(noisy.train_len(), generated.train_len());
    let mut changed = 0;
    for k in 0..generated.train_len() {
        assert_eq!(noisy.train_batch(&[k]).1, generated.train_batch(&[k]).1, "example {k}: other labels");
        let (a, b) = (raw(&noisy, k), raw(&generated, k));
        let std = &generated.standardizer().std;
        let differs = generated
            .standardizer()
            .columns
            .iter()
            .enumerate()
            .any(|(i, c)| a.get(c).is_some_and(|x| (x - b[c]).abs() > 1e-3 * (std[i] + b[c].abs())));
        changed += differs as usize;
    }
    let n = generated.train_len();
    assert!((n / 2 - 11..=n / 2 + 11).contains(&changed), "{changed} of {n} examples noisy");
}

/// A log noisier than simulation (a real robot's): the residual the prior's parameters leave is measured per joint
/// and weights the evidence. On a simulated log nothing changes; with white effort noise added, the measured noise
/// is the effort noise: `sqrt(PAIRED_NOISE_GAIN)` times the true parameters' NRMSE on the paired torques as the full
/// regressor computes it independently (the fit takes up at most its 30 directions' share of the noise, under 1 %
/// of some 10^4 rows, and only along directions the data see), and the evidence is divided by its variance.
#[test]
fn a_noisy_logs_evidence_is_weighted_by_the_noise_its_residual_shows() {
    let cfg = GeneratorConfig::default();
    let prior = generator_prior(&cfg, 41).unwrap();
    let spec = WindowSpec::default();
    let shards = tempfile::tempdir().unwrap();
    let (path, _) = common::write_shard(&Job { seed: 4, robot: 1, trajectory: 2 }, shards.path());
    let clean = read(&path, None).unwrap();
    let plain = recording_evidence(&clean, &prior, &spec).unwrap();
    let measured = measured_evidence(&clean, &prior, &spec).unwrap();
    assert!(measured.whole == plain.1 && measured.windows == plain.0, "simulated evidence changed");
    assert!(measured.noise.iter().all(|&n| n < 1e-4), "noise measured on a simulated log: {:?}", measured.noise);

    // White noise on every effort sample, each joint at 1e-3 of its torque's RMS.
    let mut noisy = clean.clone();
    let dof = noisy.trajectory.joints();
    let rms: Vec<f64> = (0..dof)
        .map(|j| {
            let tau = noisy.trajectory.tau.iter().skip(j).step_by(dof);
            (tau.map(|t| t * t).sum::<f64>() / noisy.trajectory.len() as f64).sqrt()
        })
        .collect();
    let mut rng = dynforge_robot::rng::Rng::stream(5, &[1]);
    for (i, t) in noisy.trajectory.tau.iter_mut().enumerate() {
        *t += 1e-3 * rms[i % dof] * rng.normal();
    }
    let m = measured_evidence(&noisy, &prior, &spec).unwrap();
    let mut normal = dynforge_identify::NormalEquations::new(dof);
    normal.add(&noisy.model, &noisy.trajectory).unwrap();
    let truth = normal.nrmse(&dynamic_parameters(&noisy.model));
    for j in 0..dof {
        let expected = PAIRED_NOISE_GAIN.sqrt() * truth[j];
        assert!((m.noise[j] / expected - 1.0).abs() < 0.05, "joint {j}: measured {:?}, paired {truth:?}", m.noise);
    }
    // The noise now dominates the floor by orders of magnitude, and the evidence shrinks accordingly.
    let unweighted = recording_evidence(&noisy, &prior, &spec).unwrap().1;
    let trace = |e: &Evidence| (0..e.rank).map(|i| e.h[i * e.rank - i * (i + 1) / 2 + i]).sum::<f64>();
    let ratio = trace(&m.whole) / trace(&unweighted);
    assert!(ratio < 1e-2, "the noisy log's evidence kept {ratio:.3e} of its weight");
}
