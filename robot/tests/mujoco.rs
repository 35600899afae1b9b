//! Generated URDFs load in MuJoCo (PyPI `mujoco`) with the same dynamics: mass matrix and bias forces agree with
//! ours to rounding. Needs the reference venv (see `dynforge_testkit::reference_python`).

mod common;

use common::{random_state, robot};
use dynforge_robot::rng::Rng;
use dynforge_robot::{Data, crba, nonlinear_effects};
use serde_json::{Value, json};

#[test]
fn mujoco_loads_generated_urdfs_with_identical_dynamics() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference/mujoco_dynamics.py");
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng::stream(77, &[]);
    for id in [1, 23] {
        let r = robot(id);
        let path = dir.path().join(format!("robot{id}.urdf"));
        std::fs::write(&path, r.urdf()).unwrap();
        let states: Vec<_> = (0..10).map(|_| random_state(&r.model, &mut rng)).collect();
        let request = json!({
            "urdf": path,
            "states": states.iter().map(|(q, qd, _)| json!({"q": q, "qd": qd})).collect::<Vec<_>>(),
        });
        let reply: Value =
            serde_json::from_str(&dynforge_testkit::run_python(&py, &script, &[], &request.to_string())).unwrap();
        let mut data = Data::new(&r.model);
        for ((q, qd, _), theirs) in states.iter().zip(reply.as_array().unwrap()) {
            assert_eq!(theirs["nq"], 6, "MuJoCo sees the six revolute joints");
            let m = crba(&r.model, &mut data, q).clone();
            let scale = m.abs().max();
            for (i, row) in theirs["mass_matrix"].as_array().unwrap().iter().enumerate() {
                for (j, v) in row.as_array().unwrap().iter().enumerate() {
                    // Two evaluations of the same sums: agreement to a few hundred eps of the largest entry.
                    assert!((m[(i, j)] - v.as_f64().unwrap()).abs() < 1e-12 * scale, "M[{i},{j}] robot {id}");
                }
            }
            let b = nonlinear_effects(&r.model, &mut data, q, qd).to_vec();
            let scale = b.iter().fold(1.0f64, |a, x| a.max(x.abs()));
            for (j, v) in theirs["bias"].as_array().unwrap().iter().enumerate() {
                assert!((b[j] - v.as_f64().unwrap()).abs() < 1e-10 * scale, "bias[{j}] robot {id}");
            }
        }
    }
}
