//! The robot generator: determinism, validity and the configured ranges.

use dynforge_proto::{LABELS, LabelKind};
use dynforge_robot::generator::{GeneratorConfig, SectionKind, generate};
use dynforge_robot::model::check_physical;
use dynforge_robot::parameters::labels;
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
        let y = labels(&r.model).unwrap();
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
