//! Identification on motions with exactly known torques (inverse dynamics of analytic joint trajectories).

use dynforge_identify::{NormalEquations, Prior, least_squares, parameters_of_labels, refine};
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};
use dynforge_recording::JointTrajectory;
use dynforge_robot::Model;
use dynforge_robot::generator::generate;
use dynforge_robot::parameters::{dynamic_parameters, labels_of};
use dynforge_testkit::sinusoid_recording;

const DT: f64 = 1e-3;

fn normal_equations(model: &Model, variant: u32, samples: usize) -> NormalEquations {
    NormalEquations::of(model, &sinusoid_recording(model, variant, DT, samples)).unwrap()
}

/// `count` bags `{stem}K.mcap` in `dir` of `truth`'s sinusoid motions `K` (`samples` each), with `urdf` as their
/// robot description.
fn bags(
    dir: &std::path::Path,
    stem: &str,
    urdf: &str,
    truth: &Model,
    (count, samples): (u32, usize),
) -> Vec<std::path::PathBuf> {
    (0..count)
        .map(|variant| {
            let path = dir.join(format!("{stem}{variant}.mcap"));
            dynforge_testkit::write_bag(&path, urdf, &sinusoid_recording(truth, variant, DT, samples));
            path
        })
        .collect()
}

fn robot(id: u64) -> Model {
    generate(&GeneratorConfig::default(), 5, id).unwrap().model
}

/// Central differences of qd err by `w^2 dt^2 / 6` of qdd (w <= 3.6 rad/s here: 2.2e-6), which bounds the torque
/// error of the true parameters relative to the torque spread well below 1e-4.
const DIFFERENCE_BOUND: f64 = 1e-4;

#[test]
fn least_squares_predicts_the_torques_of_another_motion() {
    let truth = robot(0);
    let fit = normal_equations(&truth, 0, 4000);
    let held_out = normal_equations(&truth, 1, 4000);
    assert!(held_out.mean_nrmse(&dynamic_parameters(&truth)) < DIFFERENCE_BOUND);
    let ls = least_squares(&fit).unwrap();
    // Some combinations are never identifiable from joint torques (e.g. link 1's parameters other than Izz).
    assert!(ls.rank < 72 && ls.rank >= 12, "rank {}", ls.rank);
    let nrmse = held_out.mean_nrmse(&ls.pi);
    assert!(nrmse < DIFFERENCE_BOUND, "held-out NRMSE {nrmse:.3e} ({:?})", held_out.nrmse(&ls.pi));
    // The fit's own residual is the finite-difference error too.
    assert!(fit.mean_nrmse(&ls.pi) <= fit.mean_nrmse(&dynamic_parameters(&truth)) * (1.0 + 1e-6));
}

#[test]
fn refining_a_wrong_prior_fits_the_torques_and_recovers_friction() {
    let truth = robot(1);
    let wrong = labels_of(&robot(2)).unwrap();
    let true_labels = labels_of(&truth).unwrap();
    let std: [f64; NUM_LABELS] = std::array::from_fn(|k| (true_labels[k] - wrong[k]).abs() * 2.0 + 1e-3);
    let prior = Prior::new(wrong, &std).unwrap();
    let fit = normal_equations(&truth, 0, 4000);
    let held_out = normal_equations(&truth, 1, 4000);
    let ls = least_squares(&fit).unwrap();
    let refined = refine(&fit, &truth, &prior, ls.sigma).unwrap();
    // The prior's torques are far off; the refined labels predict another motion to within the noise floor
    // (NOISE_FLOOR = 1e-3 of the torque RMS) that the refinement assumes.
    let before = held_out.mean_nrmse(&parameters_of_labels(&truth, &wrong));
    let after = held_out.mean_nrmse(&parameters_of_labels(&truth, &refined.labels));
    assert!(before > 1e-2, "the prior should be wrong: {before}");
    assert!(after < 1e-3, "refined NRMSE {after:.3e} (prior {before:.3e}), {} iterations", refined.iterations);
    // Friction columns (sign(qd), qd of one joint) are independent of everything else: the data determine them.
    // Their posterior std is ~sigma / sqrt(rows) ~ 1e-3 * RMS(tau) / 60, so the prior moves them by ~(that / std)^2
    // of its offset: far below 1 % of the prior std.
    for (k, l) in LABELS.iter().enumerate() {
        if matches!(l.kind, LabelKind::Coulomb | LabelKind::Viscous) {
            let err = (refined.labels[k] - true_labels[k]).abs();
            assert!(
                err < 1e-2 * std[k],
                "{}: {} vs {} (prior {})",
                l.name,
                refined.labels[k],
                true_labels[k],
                wrong[k]
            );
        }
    }
}

#[test]
fn the_truth_as_prior_is_a_fixed_point() {
    let truth = robot(3);
    let y = labels_of(&truth).unwrap();
    let prior = Prior::new(y, &std::array::from_fn(|k| 0.1 * y[k].abs().max(1e-3))).unwrap();
    let fit = normal_equations(&truth, 0, 2000);
    let refined = refine(&fit, &truth, &prior, 0.0).unwrap();
    for (k, l) in LABELS.iter().enumerate() {
        // The data's optimum is the truth up to the finite-difference error, which moves labels by far less than
        // 1e-3 of their prior std.
        assert!(
            (refined.labels[k] - y[k]).abs() < 1e-3 * prior.std()[k],
            "{}: {} vs {}",
            l.name,
            refined.labels[k],
            y[k]
        );
    }
}

#[test]
fn no_motion_and_bad_priors_are_errors() {
    let truth = robot(4);
    let moving = sinusoid_recording(&truth, 0, DT, 100);
    let still = JointTrajectory { qd: vec![0.0; moving.qd.len()], ..moving.clone() };
    let empty = NormalEquations::of(&truth, &still).unwrap();
    assert!(least_squares(&empty).is_err());
    let moving_ne = NormalEquations::of(&truth, &moving).unwrap();
    assert!(least_squares(&moving_ne).is_ok());
    let y = labels_of(&truth).unwrap();
    let mut std = [1.0; NUM_LABELS];
    std[7] = 0.0;
    let err = Prior::new(y, &std).unwrap_err().to_string();
    assert!(err.contains(LABELS[7].name), "{err}");
    std[7] = f64::NAN;
    assert!(Prior::new(y, &std).is_err());
    let five = |v: &[f64]| v.chunks_exact(6).flat_map(|c| c[..5].to_vec()).collect::<Vec<f64>>();
    let short = JointTrajectory {
        names: moving.names[..5].to_vec(),
        t: moving.t.clone(),
        q: five(&moving.q),
        qd: five(&moving.qd),
        tau: five(&moving.tau),
    };
    assert!(NormalEquations::of(&truth, &short).is_err());
}

#[test]
fn a_frictionless_description_is_calibrated_to_its_robot_s_friction_and_torques() {
    // CAD exports usually carry no friction: the prior's floor (2 % of the effort limit) still lets the data in.
    use dynforge_identify::calibrate::{Options, identify_logs};
    use dynforge_robot::model::Friction;
    let truth = robot(8);
    let inertials: Vec<_> = truth.links().iter().map(|l| l.inertial).collect();
    let cad = truth.with_dynamics(&inertials, &[Friction::default(); 6]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let urdf = dynforge_robot::urdf::to_string(&cad, &Default::default());
    let logs = bags(dir.path(), "log", &urdf, &truth, (2, 4000));
    let (id, _) = identify_logs(&logs, None, &Options::default()).unwrap();
    assert!(id.nrmse_urdf > 1e-2 && id.nrmse_calibrated < 1e-4, "{} -> {}", id.nrmse_urdf, id.nrmse_calibrated);
    let y = labels_of(&truth).unwrap();
    for (k, l) in LABELS.iter().enumerate() {
        let j = l.index;
        let value = match l.kind {
            LabelKind::Coulomb => id.joints[j].coulomb.value,
            LabelKind::Viscous => id.joints[j].viscous.value,
            _ => continue,
        };
        // Exactly known torques and independent friction columns: within the difference error (2e-6 of the
        // torque), far below 1e-4 of the coefficient.
        assert!((value - y[k]).abs() < 1e-4 * y[k].max(1.0), "{}: {value} vs {}", l.name, y[k]);
    }
}

#[test]
fn the_generated_arms_have_48_identifiable_combinations() {
    // 36 inertial combinations and the 12 friction coefficients: the regressor's row space depends on the
    // kinematics alone, so every robot and any rich enough motion give the same count. (A column that no torque
    // depends on is zero only up to rounding: scaled to unit norm it would pass for a 49th.)
    for id in [0, 3, 6] {
        let truth = robot(id);
        let mut ne = NormalEquations::new(6);
        for variant in 0..4 {
            ne.merge(&normal_equations(&truth, variant, 4000));
        }
        assert_eq!(least_squares(&ne).unwrap().rank, 48, "robot {id}");
    }
}

/// What `identify` reports as a friction's standard deviation is the scatter of its value over draws of the effort
/// noise: 16 draws of 1 % white noise on two 4 s logs of a generated arm, velocity as logged. Each of the 12
/// friction parameters' scatter is a sample standard deviation of 16 values (relative standard error
/// `1 / sqrt(30)`, 18 %); pooled over the 12 as a mean squared ratio, ~5 %, so 0.7-1.4 is ~6 standard errors wide and
/// a covariance off by any factor that matters (a wrong scale of the scores, of the rows) falls outside (measured:
/// 0.99). White noise is where the sandwich and the Laplace covariance agree; where they part (a residual coloured
/// by the velocity filter, MuJoCo's logs) is measured by `dynforge-bench-calibrate` (docs/measurements.md).
#[test]
fn friction_spreads_are_the_scatter_of_friction_over_noise_draws() {
    use dynforge_identify::calibrate::{Options, identify_logs};
    use dynforge_identify::signals::{Conditioning, EffortConvention, VelocitySource};
    use dynforge_robot::rng::Rng;
    let truth = robot(8);
    let n = truth.dof();
    let urdf = dynforge_robot::urdf::to_string(&truth, &Default::default());
    let dir = tempfile::tempdir().unwrap();
    let clean: Vec<JointTrajectory> = (0..2).map(|v| sinusoid_recording(&truth, v, DT, 4000)).collect();
    let rms: Vec<f64> = (0..n)
        .map(|j| (clean[0].tau.iter().skip(j).step_by(n).map(|t| t * t).sum::<f64>() / clean[0].len() as f64).sqrt())
        .collect();
    let options = Options {
        conditioning: Conditioning {
            effort: Some(EffortConvention::Held),
            velocity: Some(VelocitySource::Logged),
            cutoff: None,
        },
        ..Options::default()
    };
    let (mut values, mut stds) = (vec![Vec::new(); 2 * n], vec![Vec::new(); 2 * n]);
    for draw in 0..16u64 {
        let logs: Vec<_> = clean
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let mut noisy = c.clone();
                let mut rng = Rng::stream(draw, &[k as u64]);
                noisy.tau.iter_mut().enumerate().for_each(|(i, t)| *t += 0.01 * rms[i % n] * rng.normal());
                let path = dir.path().join(format!("log{k}.mcap"));
                dynforge_testkit::write_bag(&path, &urdf, &noisy);
                path
            })
            .collect();
        let (id, _) = identify_logs(&logs, None, &options).unwrap();
        for (j, joint) in id.joints.iter().enumerate() {
            for (k, e) in [(2 * j, &joint.coulomb), (2 * j + 1, &joint.viscous)] {
                values[k].push(e.value);
                stds[k].push(e.std);
            }
        }
    }
    let ratio = (0..2 * n)
        .map(|k| {
            let m = values[k].iter().sum::<f64>() / 16.0;
            let scatter = values[k].iter().map(|v| (v - m).powi(2)).sum::<f64>() / 15.0;
            let reported = stds[k].iter().map(|s| s * s).sum::<f64>() / 16.0;
            reported / scatter
        })
        .sum::<f64>()
        / (2 * n) as f64;
    assert!((0.7..1.4).contains(&ratio), "reported variance over scatter: {ratio}");
}

#[test]
fn robots_drawn_from_the_prior_are_calibrated_to_their_torques_from_clean_logs() {
    // Exact torques pin the identifiable combinations to the difference error, so the MAP lies in a valley that
    // narrow in the log-Cholesky coordinates. Searched at full weight from the description, Levenberg-Marquardt left
    // robot 1 at 5e-5 of the torque unexplained (least squares: 4e-7) and drove robot 3's first link to a degenerate
    // body; the continuation in the data's weight reaches the optimum.
    // Bound: the optimum's objective is at most the truth's, whose data cost is the difference error's (~0) and whose
    // prior cost is half a chi-square of 72 degrees (36 +- 8.5). So the data cost is under ~60: a residual RMS under
    // NOISE_FLOOR sqrt(120 / 72,000) = 4e-6 of the torque's RMS (the weights' noise is that floor here), and NRMSE,
    // against the torque's spread, under 1e-5 for joints whose torque is up to half gravity's mean.
    use dynforge_identify::calibrate::{NOISE_FLOOR, Options, identify_logs};
    use dynforge_proto::spread::Spread;
    use dynforge_robot::prior::CoordinatePrior;
    let dir = tempfile::tempdir().unwrap();
    for id in 0..8u64 {
        let nominal = robot(20 + id);
        let prior = CoordinatePrior::of(&nominal, Spread::uniform(0.3)).unwrap();
        let mut rng = dynforge_robot::rng::Rng::stream(11, &[id]);
        let truth = prior.draw_variant(&nominal, || rng.normal()).unwrap();
        let urdf = dynforge_robot::urdf::to_string(&nominal, &Default::default());
        let logs = bags(dir.path(), &format!("robot{id}-log"), &urdf, &truth, (4, 3000));
        let options = Options { spread: Spread::uniform(0.3), ..Options::default() };
        let (found, _) = identify_logs(&logs, None, &options).unwrap();
        assert!(found.converged, "robot {id}: the search did not converge in {} iterations", found.iterations);
        assert!(
            found.nrmse_calibrated < 0.1 * NOISE_FLOOR,
            "robot {id}: calibrated NRMSE {:.2e}, least squares {:.2e}",
            found.nrmse_calibrated,
            found.nrmse_least_squares
        );
    }
}
