//! Our dynamics against Pinocchio (an independent C++ implementation) on the UR5 URDF shipped by the PyPI package
//! example-robot-data and on generated robots.
//!
//! Needs the reference venv (see `dynforge_testkit::reference_python`).

mod common;

use common::{random_state, robot};
use dynforge_proto::params::INERTIAL_PARAMS_PER_LINK as NI;
use dynforge_robot::rng::Rng;
use dynforge_robot::{
    Data, Model, aba, crba, forward_kinematics, nonlinear_effects, point_jacobian, regressor, rnea, urdf,
};
use nalgebra::{DMatrix, Vector3};
use serde_json::{Value, json};

const SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/reference/pinocchio_dynamics.py");

fn run_python(py: &str, args: &[&str], stdin: &str) -> String {
    dynforge_testkit::run_python(py, std::path::Path::new(SCRIPT), args, stdin)
}

fn vec(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

fn mat(v: &Value) -> DMatrix<f64> {
    let rows: Vec<Vec<f64>> = v.as_array().unwrap().iter().map(vec).collect();
    DMatrix::from_fn(rows.len(), rows[0].len(), |r, c| rows[r][c])
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// Compares every algorithm on 25 random states. Tolerances: both sides evaluate the same sums in another order,
/// so forward evaluations (RNEA, CRBA, regressor, Jacobian) agree to a few hundred eps times the magnitude of the
/// terms (1e-10 relative is a >100x margin); ABA solves M x = r and agrees to ~cond(M) eps.
fn compare(py: &str, model: &Model, urdf_path: &str, seed: u64) {
    compare_locked(py, model, urdf_path, &json!({}), seed)
}

/// [`compare`] against Pinocchio's model of `urdf_path` with the joints of `lock` held at their positions.
fn compare_locked(py: &str, model: &Model, urdf_path: &str, lock: &Value, seed: u64) {
    let mut rng = Rng::stream(seed, &[]);
    let mut data = Data::new(model);
    let states: Vec<_> = (0..25)
        .map(|_| {
            let (q, qd, qdd) = random_state(model, &mut rng);
            let tau: Vec<f64> = model.joints().iter().map(|j| rng.uniform(-0.2, 0.2) * j.limits.effort).collect();
            (q, qd, qdd, tau)
        })
        .collect();
    let request = json!({
        "urdf": urdf_path,
        "lock": lock,
        "states": states.iter().map(|(q, qd, qdd, tau)| json!({"q": q, "qd": qd, "qdd": qdd, "tau": tau})).collect::<Vec<_>>(),
    });
    let reply: Value = serde_json::from_str(&run_python(py, &[], &request.to_string())).unwrap();
    let n = model.dof();
    for ((q, qd, qdd, tau), want) in states.iter().zip(reply.as_array().unwrap()) {
        let ours = rnea(model, &mut data, q, qd, qdd).to_vec();
        let theirs = vec(&want["rnea"]);
        let scale = theirs.iter().fold(1.0f64, |m, x| m.max(x.abs()));
        assert!(max_diff(&ours, &theirs) < 1e-10 * scale, "rnea {ours:?} vs {theirs:?}");

        let ours = nonlinear_effects(model, &mut data, q, qd).to_vec();
        assert!(max_diff(&ours, &vec(&want["nle"])) < 1e-10 * scale, "nle");

        let m = crba(model, &mut data, q).clone();
        let theirs = mat(&want["crba"]);
        assert!((&m - &theirs).abs().max() < 1e-10 * theirs.abs().max(), "crba\n{m}\nvs\n{theirs}");

        let ev = m.clone().symmetric_eigenvalues();
        let ours = aba(model, &mut data, q, qd, tau).to_vec();
        let theirs = vec(&want["aba"]);
        let norm = theirs.iter().map(|x| x * x).sum::<f64>().sqrt();
        let tol = 100.0 * ev.max() / ev.min() * f64::EPSILON * norm.max(1.0);
        assert!(max_diff(&ours, &theirs) < tol, "aba {ours:?} vs {theirs:?} (tol {tol})");

        let y = regressor(model, &mut data, q, qd, qdd).clone();
        let theirs = mat(&want["regressor"]);
        let ours = y.columns(0, NI * n);
        assert!((ours - &theirs).abs().max() < 1e-10 * theirs.abs().max(), "regressor");

        forward_kinematics(model, &mut data, q);
        point_jacobian(model, &mut data, n - 1, &Vector3::zeros());
        let theirs = mat(&want["jacobian"]);
        assert!((&data.jacobian - &theirs).abs().max() < 1e-12, "jacobian\n{}\nvs\n{theirs}", data.jacobian);
    }
}

#[test]
fn matches_pinocchio_on_the_ur5_of_example_robot_data() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let path = run_python(&py, &["--ur5"], "").trim().to_string();
    let model = urdf::load(&path).expect("the UR5 URDF loads");
    assert_eq!(model.dof(), 6);
    assert_eq!(model.joints()[0].name, "shoulder_pan_joint");
    assert_eq!(model.links()[5].name, "wrist_3_link");
    compare(&py, &model, &path, 21);
}

#[test]
fn matches_pinocchio_on_generated_robots() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    for id in [0, 17, 99] {
        let r = robot(id);
        let path = dir.path().join(format!("robot{id}.urdf"));
        std::fs::write(&path, r.urdf()).unwrap();
        compare(&py, &r.model, path.to_str().unwrap(), 30 + id);
    }
}

#[test]
fn matches_pinocchio_on_the_panda_with_its_prismatic_finger_and_welded_joints() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let path = run_python(&py, &["--panda"], "").trim().to_string();
    let text = std::fs::read_to_string(&path).unwrap();
    // The mimic finger is welded at 0; the other finger stays a prismatic joint of the chain.
    let model = urdf::parse(&text, &path).expect("the Panda URDF loads");
    assert_eq!(model.dof(), 8);
    assert_eq!(model.joints()[7].name, "panda_finger_joint1");
    assert!(model.is_prismatic(7) && (0..7).all(|i| !model.is_prismatic(i)));
    compare_locked(&py, &model, &path, &json!({"panda_finger_joint2": 0.0}), 23);
    // Welded where a log holds them: the fingers open 2 cm and 3 cm (a mimic joint's own position may be given).
    let welds: urdf::Welds =
        [("panda_finger_joint1".to_string(), 0.02), ("panda_finger_joint2".to_string(), 0.03)].into();
    let arm = urdf::parse_welded(&text, &path, &welds).expect("the Panda loads with its fingers welded");
    assert_eq!(arm.dof(), 7);
    let lock = json!({"panda_finger_joint1": 0.02, "panda_finger_joint2": 0.03});
    compare_locked(&py, &arm, &path, &lock, 24);
}
