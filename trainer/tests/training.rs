//! The estimator's training loop and checkpoints on small synthetic corpora: it can fit, it saves and loads
//! exactly, and an interrupted run resumes to the very same result.

#[path = "../../dataset/tests/common/mod.rs"]
mod common;

use std::sync::atomic::{AtomicBool, Ordering};

use burn::tensor::Device;
use dynforge_dataset::cache::windows::CachedWindows;
use dynforge_dataset::examples::Examples;
use dynforge_dataset::examples::corpus::Corpus;
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::metrics::EpochMetrics;
use dynforge_dataset::normalize::Standardizer;
use dynforge_dataset::window::WindowSpec;
use dynforge_robot::rng::Rng;
use dynforge_trainer::checkpoint::Checkpoint;
use dynforge_trainer::model::{NetworkConfig, TransformerConfig};
use dynforge_trainer::training::{Run, TrainConfig, TrainObserver, predict, train};

const LEN: usize = 8;
const WIDTH: usize = 5;

/// `n` windows of random values; each label is a fixed linear function of the window's mean inputs, so a model
/// can learn it.
fn corpus(n: usize, seed: u64) -> Corpus {
    let mut rng = Rng::stream(seed, &[1]);
    let mut data = Vec::new();
    let mut labels = Vec::new();
    for _ in 0..n {
        let w: Vec<f32> = (0..LEN * WIDTH).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
        let means: Vec<f64> =
            (0..WIDTH).map(|c| w.iter().skip(c).step_by(WIDTH).map(|v| *v as f64).sum::<f64>()).collect();
        labels.push(std::array::from_fn(|k| means[k % WIDTH] * (1.0 + k as f64 / 10.0) + k as f64));
        data.extend(w);
    }
    let windows = CachedWindows {
        spec: WindowSpec::new(LEN, 1, 1),
        width: WIDTH,
        data,
        labels,
        robots: (0..n as u64).collect(),
        trajectories: vec![0; n],
        hit: false,
    };
    let all: Vec<usize> = (0..n).collect();
    let standardizer = Standardizer::fit(&windows, &all);
    Corpus { windows, train: all.clone(), validation: all, standardizer }
}

fn small_model() -> TransformerConfig {
    TransformerConfig {
        inputs: WIDTH,
        seq_len: LEN,
        layers: 1,
        heads: 2,
        d_model: 32,
        d_ff: 64,
        patch: 2,
        dropout: 0.0,
    }
}

const SHAPE: [usize; 2] = [LEN, WIDTH];

fn checkpoint(c: &Corpus, model: TransformerConfig) -> Checkpoint {
    let robot = dynforge_robot::generator::generate(&Default::default(), 0, 0).unwrap().model;
    let features = JacobianFeatures::new(&robot);
    let mut ck =
        Checkpoint::new(NetworkConfig::Transformer(model), &c.windows.spec, &robot, Some(&features), &c.standardizer);
    ck.validation_fraction = 0.5;
    ck
}

/// burn's random state is process-wide: tests that create models take turns, so each run sees only its own seeding.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn a_model_overfits_a_tiny_set_by_orders_of_magnitude() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let mut c = corpus(16, 1);
    let dir = tempfile::tempdir().unwrap();
    let cfg = TrainConfig {
        epochs: 400,
        batch: 16,
        lr: 3e-3,
        warmup: 0.02,
        weight_decay: 0.0,
        patience: 1000,
        ..TrainConfig::default()
    };
    let ck = checkpoint(&c, small_model());
    let summary = train(
        &mut c,
        None,
        ck,
        &Run { dir: dir.path(), config: &cfg, resume: false, stop: &AtomicBool::new(false) },
        &mut (),
    )
    .unwrap();
    let first = summary.history[0].train_loss;
    let best = summary.history.iter().map(|m| m.validation_loss).fold(f64::INFINITY, f64::min);
    // Standardised targets start near unit loss; fitting 16 windows must drive it down by >= 2 orders.
    assert!(first > 0.3 && best < first * 1e-2, "first {first}, best {best}");
    // The saved metrics are those reported, one line per epoch.
    let csv = std::fs::read_to_string(dir.path().join("metrics.csv")).unwrap();
    assert_eq!(csv.lines().count(), summary.history.len() + 1);
}

#[test]
fn saved_and_loaded_checkpoints_predict_identically() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let c = corpus(6, 2);
    let dir = tempfile::tempdir().unwrap();
    let device = Device::default();
    let cfg = small_model();
    let model = NetworkConfig::Transformer(cfg.clone()).init(&device).unwrap();
    let ck = checkpoint(&c, cfg);
    ck.save(dir.path(), &model).unwrap();
    let (back, loaded) = Checkpoint::load(dir.path(), &device).unwrap();
    assert_eq!(back, ck);
    let x: Vec<f32> = (0..6).flat_map(|i| c.standardizer.inputs(&c.windows, i)).collect();
    let a = predict(&model, &x, 6, SHAPE, &device);
    let b = predict(&loaded, &x, 6, SHAPE, &device);
    assert_eq!(a, b);
    assert!(a.iter().flatten().any(|v| *v != 0.0));
    // A damaged weights file is an error naming it, not a panic.
    std::fs::write(dir.path().join("model.safetensors"), b"not safetensors").unwrap();
    let e = match Checkpoint::load(dir.path(), &device) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("damaged weights accepted"),
    };
    assert!(e.contains("model.safetensors"), "{e}");
}

/// Requests a stop after `at` steps.
struct StopAt<'a> {
    at: usize,
    seen: usize,
    flag: &'a AtomicBool,
}

impl TrainObserver for StopAt<'_> {
    fn step(&mut self, _: usize, _: usize, _: usize, _: f64) {
        self.seen += 1;
        if self.seen == self.at {
            self.flag.store(true, Ordering::Relaxed);
        }
    }
    fn epoch(&mut self, _: &EpochMetrics, _: bool) {}
}

#[test]
fn an_interrupted_run_resumes_to_exactly_the_uninterrupted_result() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let model = TransformerConfig { dropout: 0.1, ..small_model() };
    let cfg = TrainConfig { epochs: 3, batch: 4, lr: 2e-3, ..TrainConfig::default() };
    let whole = tempfile::tempdir().unwrap();
    let mut c = corpus(12, 3);
    let ck = checkpoint(&c, model.clone());
    let a = train(
        &mut c,
        None,
        ck.clone(),
        &Run { dir: whole.path(), config: &cfg, resume: false, stop: &AtomicBool::new(false) },
        &mut (),
    )
    .unwrap();
    // The same run, stopped mid-epoch 1 (step 5 of 3 x 3), then resumed.
    let parts = tempfile::tempdir().unwrap();
    let flag = AtomicBool::new(false);
    let stopped = train(
        &mut c,
        None,
        ck.clone(),
        &Run { dir: parts.path(), config: &cfg, resume: false, stop: &flag },
        &mut StopAt { at: 5, seen: 0, flag: &flag },
    )
    .unwrap();
    assert!(stopped.interrupted && stopped.history.len() == 1);
    let b = train(
        &mut c,
        None,
        ck,
        &Run { dir: parts.path(), config: &cfg, resume: true, stop: &AtomicBool::new(false) },
        &mut (),
    )
    .unwrap();
    assert!(!b.interrupted);
    let losses = |h: &[EpochMetrics]| h.iter().map(|m| (m.train_loss, m.validation_loss)).collect::<Vec<_>>();
    assert_eq!(losses(&a.history), losses(&b.history));
    // The interrupted epoch reports its whole cost, both stretches: all its windows over all its seconds.
    let windows = |h: &[EpochMetrics]| h.iter().map(|m| (m.windows_per_second * m.seconds).round()).collect::<Vec<_>>();
    assert_eq!(windows(&b.history), windows(&a.history));
    assert_eq!(windows(&a.history), vec![c.train_len() as f64; 3]);
    // The weights are the same (the files' headers may list metadata in another order): identical predictions.
    let device = Device::default();
    let (_, m1) = Checkpoint::load(whole.path(), &device).unwrap();
    let (_, m2) = Checkpoint::load(parts.path(), &device).unwrap();
    let x: Vec<f32> = (0..12).flat_map(|i| c.standardizer.inputs(&c.windows, i)).collect();
    assert_eq!(predict(&m1, &x, 12, SHAPE, &device), predict(&m2, &x, 12, SHAPE, &device));
    assert_eq!(a.history.len(), 3);
}

/// Collects the messages of a run.
struct Messages(Vec<String>);

impl TrainObserver for Messages {
    fn message(&mut self, text: &str) {
        self.0.push(text.to_string());
    }
}

#[test]
fn a_resume_names_its_epoch_and_every_changed_setting_and_refuses_those_that_decide_the_batches() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let cfg = TrainConfig { epochs: 1, batch: 4, lr: 2e-3, ..TrainConfig::default() };
    let dir = tempfile::tempdir().unwrap();
    let mut c = corpus(8, 3);
    let ck = checkpoint(&c, small_model());
    let never = AtomicBool::new(false);
    train(&mut c, None, ck.clone(), &Run { dir: dir.path(), config: &cfg, resume: false, stop: &never }, &mut ())
        .unwrap();
    let longer = TrainConfig { epochs: 2, lr: 1e-3, ..cfg.clone() };
    let mut seen = Messages(Vec::new());
    let r = train(
        &mut c,
        None,
        ck.clone(),
        &Run { dir: dir.path(), config: &longer, resume: true, stop: &never },
        &mut seen,
    )
    .unwrap();
    assert_eq!(r.history.len(), 2);
    let text = seen.0.join("\n");
    assert!(
        text.contains("at epoch 1") && text.contains("epochs 1 -> 2") && text.contains("lr 0.002 -> 0.001"),
        "{text}"
    );
    assert!(!text.contains("patience"), "unchanged settings are not listed: {text}");
    for other in [TrainConfig { micro_batches: 2, ..longer.clone() }, TrainConfig { batch: 3, ..longer.clone() }] {
        let e = train(
            &mut c,
            None,
            ck.clone(),
            &Run { dir: dir.path(), config: &other, resume: true, stop: &never },
            &mut (),
        )
        .map(|_| ())
        .unwrap_err();
        assert!(e.to_string().contains("micro-batches; resume it with the same"), "{e}");
    }
}

/// Counts the batches of each epoch.
struct Batches(Vec<usize>);

impl TrainObserver for Batches {
    fn step(&mut self, epoch: usize, _: usize, batches: usize, _: f64) {
        if self.0.len() == epoch {
            self.0.push(batches);
        }
    }
}

#[test]
fn following_a_growing_dataset_adds_new_shards_between_epochs_and_skips_broken_ones() {
    use dynforge_dataset::split::{Split, SplitRule, split_of};
    use dynforge_proto::job::Job;
    let dir = tempfile::tempdir().unwrap();
    // Four robots, two trajectories each; the split seed puts robots on both sides.
    let jobs: Vec<Job> =
        (0..4).flat_map(|robot| (0..2).map(move |trajectory| Job { seed: 2, robot, trajectory })).collect();
    let paths: Vec<_> = jobs.iter().map(|j| common::write_shard(j, dir.path()).0).collect();
    let broken = dir.path().join("r999999-t00-native.mcap");
    std::fs::write(&broken, b"not an mcap file").unwrap();
    let (seed, fraction) = (0..100)
        .find(|&s| {
            let sides: Vec<Split> = (0..4).map(|r| split_of(s, r, 0.5)).collect();
            sides[..2].contains(&Split::Train) && sides[..2].contains(&Split::Validation)
        })
        .map(|s| (s, 0.5))
        .unwrap();
    let robot = dynforge_robot::generator::generate(&Default::default(), 2, 0).unwrap().model;
    let features = JacobianFeatures::new(&robot);
    let empty = CachedWindows {
        spec: WindowSpec::new(8, 64, 16),
        width: 0,
        data: vec![],
        labels: vec![],
        robots: vec![],
        trajectories: vec![],
        hit: false,
    };
    let mut c = Corpus { windows: empty, train: vec![], validation: vec![], standardizer: Standardizer::fit_empty() };
    // The first two robots' shards exist when training starts.
    assert!(c.add_shards(&paths[..4], &features, &SplitRule::robots(seed, fraction)).is_empty());
    let (train0, val0) = (c.train.len(), c.validation.len());
    assert!(train0 > 0 && val0 > 0);
    c.standardizer = Standardizer::fit(&c.windows, &c.train);
    let model = TransformerConfig { inputs: c.standardizer.columns.len(), seq_len: 8, ..small_model() };
    let ck =
        Checkpoint::new(NetworkConfig::Transformer(model), &c.windows.spec, &robot, Some(&features), &c.standardizer);
    // Before epoch 1 the other shards (and a broken file) appear.
    let mut calls = 0;
    let mut skipped = Vec::new();
    let mut grow = |c: &mut Corpus| {
        if calls == 1 {
            let mut new = paths[4..].to_vec();
            new.push(broken.clone());
            skipped = c.add_shards(&new, &features, &SplitRule::robots(seed, fraction));
        }
        calls += 1;
    };
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let cfg = TrainConfig { epochs: 2, batch: 4, ..TrainConfig::default() };
    let out = tempfile::tempdir().unwrap();
    let mut batches = Batches(vec![]);
    train(
        &mut c,
        Some(&mut grow),
        ck,
        &Run { dir: out.path(), config: &cfg, resume: false, stop: &AtomicBool::new(false) },
        &mut batches,
    )
    .unwrap();
    assert_eq!(skipped.len(), 1, "{skipped:?}");
    assert!(skipped[0].to_string().contains("r999999-t00-native.mcap"), "{skipped:?}");
    // Every new window went to its robot's side, and epoch 1 trained on the grown training split.
    for (i, &r) in c.windows.robots.iter().enumerate() {
        let side = if c.train.contains(&i) { Split::Train } else { Split::Validation };
        assert_eq!(side, split_of(seed, r, fraction));
    }
    assert!(c.train.len() > train0 || c.validation.len() > val0);
    assert_eq!(batches.0, [train0.div_ceil(4), c.train.len().div_ceil(4)]);
}

#[test]
fn a_run_stopped_early_goes_on_when_resumed_with_more_patience() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let cfg = TrainConfig { epochs: 2, batch: 4, lr: 2e-3, patience: 10, ..TrainConfig::default() };
    let dir = tempfile::tempdir().unwrap();
    let mut c = corpus(8, 3);
    let ck = checkpoint(&c, small_model());
    let never = AtomicBool::new(false);
    let run = |config: &TrainConfig, c: &mut Corpus| {
        train(c, None, ck.clone(), &Run { dir: dir.path(), config, resume: true, stop: &never }, &mut ()).unwrap()
    };
    train(&mut c, None, ck.clone(), &Run { dir: dir.path(), config: &cfg, resume: false, stop: &never }, &mut ())
        .unwrap();
    // As the state file of a run with patience 1, whose best epoch was its first, records it after its second.
    let state = dir.path().join("train/state.json");
    let mut s: serde_json::Value = serde_json::from_slice(&std::fs::read(&state).unwrap()).unwrap();
    s["best_epoch"] = 0.into();
    s["stopped_early"] = true.into();
    std::fs::write(&state, serde_json::to_vec(&s).unwrap()).unwrap();
    let longer = TrainConfig { epochs: 4, patience: 1, ..cfg.clone() };
    let same = run(&longer, &mut c);
    assert!(same.stopped_early && same.history.len() == 2, "patience 1 still stops it");
    let patient = run(&TrainConfig { patience: 5, ..longer }, &mut c);
    assert!(!patient.stopped_early && patient.history.len() == 4, "patience 5 lets it train to 4 epochs");
}
