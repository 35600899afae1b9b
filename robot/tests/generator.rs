//! The robot generator: determinism, validity and the configured ranges.

use dynforge_proto::generator::{GeneratorConfig, SectionKind};
use dynforge_proto::{LABELS, LabelKind};
use dynforge_robot::generator::generate;
use dynforge_robot::model::check_physical;
use dynforge_robot::parameters::labels_of;
use std::collections::HashSet;

#[test]
fn same_seed_and_id_give_the_same_robot_in_any_order_or_thread() {
    let cfg = GeneratorConfig::default();
    let forward: Vec<String> = (0..64).map(|id| generate(&cfg, 9, id).unwrap().urdf()).collect();
    let mut backward: Vec<(u64, String)> =
        (0..64).rev().map(|id| (id, generate(&cfg, 9, id).unwrap().urdf())).collect();
    backward.reverse();
    let threaded: Vec<String> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..4u64)
            .map(|t| {
                let cfg = &cfg;
                s.spawn(move || {
                    (0..64)
                        .filter(|id| id % 4 == t)
                        .map(|id| (id, generate(cfg, 9, id).unwrap().urdf()))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        let mut all: Vec<(u64, String)> = handles.into_iter().flat_map(|h| h.join().unwrap()).collect();
        all.sort_by_key(|(id, _)| *id);
        all.into_iter().map(|(_, u)| u).collect()
    });
    for id in 0..64 {
        assert_eq!(forward[id], backward[id].1);
        assert_eq!(forward[id], threaded[id]);
    }
    assert_eq!(forward.iter().collect::<HashSet<_>>().len(), 64, "robots must differ");
    assert_ne!(generate(&cfg, 10, 0).unwrap().urdf(), forward[0], "seeds must differ");
}

#[test]
fn ten_thousand_robots_are_physical_and_within_the_configured_ranges() {
    let cfg = GeneratorConfig::default();
    let mut sections = HashSet::new();
    let k = &cfg.kinematics;
    for id in 0..10_000 {
        let r = generate(&cfg, 1, id).expect("valid");
        for i in 0..6 {
            check_physical(r.model.inertia(i)).unwrap_or_else(|e| panic!("robot {id} link {i}: {e}"));
            sections.insert(r.beams[i].section.kind());
        }
        let y = labels_of(&r.model).unwrap();
        for (v, l) in y.iter().zip(LABELS.iter()) {
            let ok = match l.kind {
                LabelKind::Coulomb => (cfg.coulomb[l.index][0]..=cfg.coulomb[l.index][1]).contains(v),
                LabelKind::Viscous => (cfg.viscous[l.index][0]..=cfg.viscous[l.index][1]).contains(v),
                LabelKind::Com => {
                    // COM at L (1/2 + g/6) with g in the configured range.
                    let len = k.link_lengths[l.index - 1];
                    let [g0, g1] = cfg.density_gradient;
                    *v >= len * (0.5 + g0 / 6.0) - 1e-12 && *v <= len * (0.5 + g1 / 6.0) + 1e-12
                }
                _ => *v > 0.0 && v.is_finite(),
            };
            assert!(ok, "robot {id}: {} = {v}", l.name);
        }
    }
    assert_eq!(sections.len(), SectionKind::ALL.len(), "every cross-section occurs");
}

#[test]
fn config_from_toml_overrides_defaults_and_rejects_bad_ranges() {
    let cfg = GeneratorConfig::from_toml("density = 7800.0\nsections = [\"tube\"]\n").unwrap();
    assert_eq!(cfg.density, 7800.0);
    let r = generate(&cfg, 3, 0).unwrap();
    assert!(r.beams.iter().all(|b| b.section.kind() == SectionKind::Tube));
    let default = generate(&GeneratorConfig::default(), 3, 0).unwrap();
    assert!(r.model.inertia(1).mass != default.model.inertia(1).mass);

    let e = GeneratorConfig::from_toml("density_gradient = [-1.5, 0.5]").unwrap_err();
    assert!(e.to_string().contains("density_gradient"), "{e}");
    let e = GeneratorConfig::from_toml("densty = 3.0").unwrap_err();
    assert!(e.to_string().contains("densty"), "{e}");
}

#[test]
fn labels_carried_onto_another_robot_read_back_exactly_and_reproduce_its_torques() {
    use dynforge_robot::parameters::model_with_labels;
    use dynforge_robot::{Data, rnea};
    let cfg = GeneratorConfig::default();
    for id in 0..20 {
        let (a, b) = (generate(&cfg, 3, id).unwrap().model, generate(&cfg, 3, id + 100).unwrap().model);
        let y = labels_of(&b).unwrap();
        let (moved, notes) = model_with_labels(&a, &y).unwrap();
        assert!(notes.is_empty(), "{notes:?}");
        let back = labels_of(&moved).unwrap();
        for k in 0..y.len() {
            assert!(
                (back[k] - y[k]).abs() <= 1e-12 * y[k].abs().max(1e-6),
                "robot {id} label {k}: {} vs {}",
                back[k],
                y[k]
            );
        }
        // Generated links have their COM on the link axis and no products of inertia, and link 1's unlabelled
        // parameters do not enter its dynamics: `b`'s torques follow from the labels alone (to rounding).
        let (q, qd, qdd) =
            ([0.3, -0.7, 1.1, 0.4, -0.2, 0.9], [0.5, -0.4, 0.3, 1.0, -0.8, 0.6], [1.0, 2.0, -1.0, 0.5, 0.3, -2.0]);
        let (mut da, mut db) = (Data::new(&moved), Data::new(&b));
        let ta = rnea(&moved, &mut da, &q, &qd, &qdd).to_vec();
        let tb = rnea(&b, &mut db, &q, &qd, &qdd);
        for j in 0..6 {
            assert!((ta[j] - tb[j]).abs() < 1e-9 * (1.0 + tb[j].abs()), "robot {id} joint {j}: {} vs {}", ta[j], tb[j]);
        }
    }
}

#[test]
fn unphysical_label_estimates_are_projected_and_each_projection_is_named() {
    use dynforge_proto::LABELS;
    use dynforge_robot::parameters::{TRIANGLE_MARGIN, model_with_labels};
    let model = generate(&GeneratorConfig::default(), 3, 0).unwrap().model;
    let mut y = labels_of(&model).unwrap();
    let at = |name: &str| LABELS.iter().position(|l| l.name == name).unwrap();
    y[at("mass_l3")] = -0.5;
    y[at("viscous_j2")] = -0.1;
    y[at("ixx_l4")] = 10.0; // far above Iyy + Izz
    let (moved, notes) = model_with_labels(&model, &y).unwrap();
    assert_eq!(notes.len(), 3, "{notes:?}");
    assert!(notes.iter().any(|n| n.starts_with("mass_l3")) && notes.iter().any(|n| n.starts_with("viscous_j2")));
    assert!(notes.iter().any(|n| n.starts_with("ixx_l4") && n.contains("triangle")));
    let back = labels_of(&moved).unwrap();
    assert!(back[at("mass_l3")] > 0.0 && back[at("viscous_j2")] == 0.0);
    // Lowered just inside the triangle inequality, not onto it.
    let others = back[at("iyy_l4")] + back[at("izz_l4")];
    assert!(back[at("ixx_l4")] < others && back[at("ixx_l4")] > others * (1.0 - 2.0 * TRIANGLE_MARGIN));
}

#[test]
fn projected_inertias_stay_strictly_inside_the_triangle_inequality_through_a_urdf_round_trip() {
    use dynforge_robot::parameters::{TRIANGLE_MARGIN, model_with_labels};
    use dynforge_robot::rng::Rng;
    let model = generate(&GeneratorConfig::default(), 3, 1).unwrap().model;
    let base = labels_of(&model).unwrap();
    let mut rng = Rng::stream(9, &[]);
    for trial in 0..500 {
        // Poor estimates: every label off by a factor 10^U(-1, 1), some negative; some links with a moment on the
        // boundary already, or one near zero (where lowering one moment could open another inequality).
        let mut y = base.map(|v| v * 10f64.powf(rng.uniform(-1.0, 1.0)) * if rng.unit() < 0.1 { -1.0 } else { 1.0 });
        if trial % 3 == 0 {
            // Link 2: ixx = iyy + izz; link 3: iyy far below the floor.
            y[23] = y[24].abs() + y[25].abs();
            y[27] = 1e-12;
        }
        let (moved, _) = model_with_labels(&model, &y).unwrap();
        let text = dynforge_robot::urdf::to_string(&moved, &Default::default());
        let back = dynforge_robot::urdf::parse(&text, "projected.urdf").unwrap();
        for link in 0..6 {
            let i = back.inertia(link).i_com();
            for a in 0..3 {
                let others = i[((a + 1) % 3, (a + 1) % 3)] + i[((a + 2) % 3, (a + 2) % 3)];
                assert!(
                    i[(a, a)] > 0.0 && i[(a, a)] <= others * (1.0 - 0.5 * TRIANGLE_MARGIN),
                    "trial {trial} link {link}: {i}"
                );
            }
        }
    }
}
