//! The paper's 38 labels as coordinates of the full parameter vector.

use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};
use dynforge_robot::Model;
use dynforge_robot::parameters::{dynamic_parameters, link_label};
use dynforge_robot::spatial::Inertia;

/// The full parameter vector `pi` of `template` with the 38 labels `y` put in, everything else (COM x and y,
/// products of inertia, link 1's mass and COM) kept from `template`. Unlike `parameters::model_with_labels` nothing is
/// projected: the map is smooth (polynomial) in `y`, as a Gauss-Newton solve needs.
pub fn parameters_of_labels(template: &Model, y: &[f64; NUM_LABELS]) -> Vec<f64> {
    let n = template.dof();
    let mut pi = dynamic_parameters(template);
    let mut mass: Vec<f64> = (0..n).map(|i| template.inertia(i).mass).collect();
    let mut com: Vec<_> = (0..n).map(|i| template.inertia(i).com()).collect();
    let mut i_com: Vec<_> = (0..n).map(|i| template.inertia(i).i_com()).collect();
    let ni = dynforge_proto::params::INERTIAL_PARAMS_PER_LINK;
    let nf = dynforge_proto::params::FRICTION_PARAMS_PER_JOINT;
    for (l, &v) in LABELS.iter().zip(y.iter()) {
        let link = l.index.wrapping_sub(1);
        match l.kind {
            LabelKind::Coulomb => pi[ni * n + nf * l.index] = v,
            LabelKind::Viscous => pi[ni * n + nf * l.index + 1] = v,
            LabelKind::Mass => mass[link] = v,
            LabelKind::Com => com[link].z = v,
            LabelKind::Ixx => i_com[link][(0, 0)] = v,
            LabelKind::Iyy => i_com[link][(1, 1)] = v,
            LabelKind::Izz => i_com[link][(2, 2)] = v,
        }
    }
    for i in 0..n {
        pi[ni * i..ni * (i + 1)].copy_from_slice(&Inertia::from_com(mass[i], com[i], i_com[i]).to_params());
    }
    pi
}

/// The 38 labels of a full parameter vector `pi` (6 joints): per link the mass, the COM along the link axis and the
/// moments about the COM, per joint the friction pair. Pure arithmetic, no physical check: `pi` may be any point of
/// parameter space, e.g. a posterior mean (a mass at or below zero gives a non-finite or meaningless COM).
pub fn labels_of_parameters(pi: &[f64]) -> [f64; NUM_LABELS] {
    let ni = dynforge_proto::params::INERTIAL_PARAMS_PER_LINK;
    let nf = dynforge_proto::params::FRICTION_PARAMS_PER_JOINT;
    let friction = ni * 6;
    std::array::from_fn(|k| {
        let l = &LABELS[k];
        match l.kind {
            LabelKind::Coulomb => pi[friction + nf * l.index],
            LabelKind::Viscous => pi[friction + nf * l.index + 1],
            kind => {
                let p: [f64; 10] = pi[ni * (l.index - 1)..ni * l.index].try_into().expect("10 parameters per link");
                link_label(kind, &Inertia::from_params(&p))
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_proto::generator::GeneratorConfig;
    use dynforge_robot::generator::generate;
    use dynforge_robot::parameters::{labels_of, model_with_labels};

    #[test]
    fn labels_of_a_robots_parameters_are_its_labels() {
        for id in 0..5 {
            let a = generate(&GeneratorConfig::default(), 3, id).unwrap().model;
            for (x, y) in labels_of_parameters(&dynamic_parameters(&a)).iter().zip(labels_of(&a).unwrap()) {
                assert!((x - y).abs() <= 1e-12 * y.abs().max(1e-9), "{x} vs {y}");
            }
        }
    }

    #[test]
    fn a_robots_own_labels_give_back_its_parameters() {
        let a = generate(&GeneratorConfig::default(), 3, 2).unwrap().model;
        for (x, r) in parameters_of_labels(&a, &labels_of(&a).unwrap()).iter().zip(dynamic_parameters(&a)) {
            assert!((x - r).abs() <= 1e-12 * r.abs().max(1e-6), "{x} vs {r}");
        }
    }

    #[test]
    fn another_robots_labels_give_that_robots_parameters() {
        let cfg = GeneratorConfig::default();
        let a = generate(&cfg, 3, 0).unwrap().model;
        let b = generate(&cfg, 3, 1).unwrap().model;
        let yb = labels_of(&b).unwrap();
        // `model_with_labels` (projected, but b's labels are physical) is the reference.
        let (reference, notes) = model_with_labels(&a, &yb).unwrap();
        assert!(notes.is_empty(), "{notes:?}");
        let ours = parameters_of_labels(&a, &yb);
        // Link 1's Ixx, Iyy (entries 4 and 6) are unlabelled: `model_with_labels` may grow them to keep link 1 physical.
        let compared = ours.iter().zip(dynamic_parameters(&reference)).enumerate().filter(|(k, _)| *k != 4 && *k != 6);
        for (k, (x, r)) in compared {
            assert!((x - r).abs() <= 1e-12 * r.abs().max(1e-6), "parameter {k}: {x} vs {r}");
        }
    }
}
