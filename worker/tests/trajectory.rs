//! Waypoints and moves.

use dynforge_robot::generator::generate;

use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::sim::TrajectoryConfig;
use dynforge_robot::{Data, forward_kinematics};
use dynforge_worker::collision::{CollisionModel, Contact};
use dynforge_worker::trajectory::Reference;
use dynforge_worker::trajectory::{Move, PathChecker, waypoints};

#[test]
fn waypoints_are_deterministic_inside_limits_and_collision_free_with_their_paths() {
    let cfg = TrajectoryConfig::default();
    for id in 0..5 {
        let r = generate(&GeneratorConfig::default(), 8, id).unwrap();
        let tour = waypoints(&r, 8, &cfg).unwrap();
        assert_eq!(tour, waypoints(&r, 8, &cfg).unwrap());
        assert_eq!(tour.len(), 16);
        // An independent checker with the exact geometry (no clearance) and a finer path step agrees.
        let mut exact = PathChecker::new(&r, 0.0, 0.005);
        for k in 0..16 {
            for (j, q) in tour[k].iter().enumerate() {
                let l = &r.model.joints()[j].limits;
                assert!(*q >= l.lower + cfg.limit_margin && *q <= l.upper - cfg.limit_margin);
            }
            assert!(exact.path_free(&tour[k], &tour[(k + 1) % 16]), "robot {id} path {k}");
        }
    }
    let r = generate(&GeneratorConfig::default(), 8, 0).unwrap();
    assert_ne!(waypoints(&r, 8, &cfg).unwrap(), waypoints(&r, 9, &cfg).unwrap(), "seeds differ");
}

#[test]
fn collisions_with_ground_and_self_are_detected() {
    let r = generate(&GeneratorConfig::default(), 8, 1).unwrap();
    let model = &r.model;
    let mut data = Data::new(model);
    let check = |data: &mut Data, q: [f64; 6]| {
        forward_kinematics(model, data, &q);
        CollisionModel::new(&r, 0.0).check(&data.o_m_i)
    };
    assert_eq!(check(&mut data, [0.0; 6]), None, "straight up is free");
    // Shoulder at 2 rad swings the 0.8 m arm below the 0.22 m shoulder height.
    assert!(matches!(check(&mut data, [0.0, 2.0, 0.0, 0.0, 0.0, 0.0]), Some(Contact::Ground { .. })));
    // Elbow and wrist 1 folded to their limits bring the wrist back onto the upper arm.
    assert_eq!(check(&mut data, [0.0, 0.0, 2.6, 2.6, 0.0, 0.0]), Some(Contact::SelfCollision { a: 2, b: 5 }));
    // Elbow folded by 3 rad (beyond its limit) drives the tool into the ground.
    assert_eq!(check(&mut data, [0.0, 0.0, 3.0, 0.0, 0.0, 0.0]), Some(Contact::Ground { link: 6 }));
}

#[test]
fn minimum_jerk_reference_starts_and_ends_at_rest() {
    let cfg = TrajectoryConfig::default();
    let r = generate(&GeneratorConfig::default(), 8, 2).unwrap();
    let tour = waypoints(&r, 8, &cfg).unwrap();
    let mv = Move::of_tour(&r.model, &tour, 15, &cfg);
    assert_eq!((mv.start, mv.goal), (tour[15], tour[0]), "the last trajectory closes the tour");
    assert!(mv.total() >= 4.096 + 1.0, "long enough for one 64 x 64 ms window and offsets");
    let [q0, v0, a0] = mv.at(0.0);
    let [q1, v1, a1] = mv.at(mv.duration);
    assert_eq!(q0, mv.start);
    for j in 0..6 {
        assert!((q1[j] - mv.goal[j]).abs() < 1e-12);
        assert!(v0[j] == 0.0 && a0[j] == 0.0 && v1[j].abs() < 1e-12 && a1[j].abs() < 1e-9);
        // Peak speed at mid-move is 1.875 dq / T and within the configured fraction of the limit.
        let [_, vm, _] = mv.at(mv.duration / 2.0);
        let dq = mv.goal[j] - mv.start[j];
        assert!((vm[j] - 1.875 * dq / mv.duration).abs() < 1e-12);
        assert!(vm[j].abs() <= cfg.speed_fraction * r.model.joints()[j].limits.velocity + 1e-12);
        // The velocity is the derivative of the position (central difference, h = 1e-6).
        let t = 0.37 * mv.duration;
        let [qp, _, _] = mv.at(t + 1e-6);
        let [qm, _, _] = mv.at(t - 1e-6);
        let [_, v, _] = mv.at(t);
        assert!(((qp[j] - qm[j]) / 2e-6 - v[j]).abs() < 1e-6);
    }
}
