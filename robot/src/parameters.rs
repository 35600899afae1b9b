//! Views of a model as parameter vectors: the 38 paper labels and the full `12 n` dynamic-parameter vector.

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI, num_params};
use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};

use crate::model::{Friction, Inertial, Model, ModelError, ModelProblem};
use crate::spatial::Inertia;

/// The paper's 38 labels (order of [`dynforge_proto::LABELS`]). Needs a 6-joint model.
pub fn labels(model: &Model) -> Result<[f64; NUM_LABELS], ModelError> {
    if model.dof() != 6 {
        return Err(ModelError {
            source_name: format!("model '{}'", model.name()),
            problem: ModelProblem::InvalidJoint {
                joint: "*".into(),
                reason: format!("labels need 6 joints, the model has {}", model.dof()),
            },
        });
    }
    let mut out = [0.0; NUM_LABELS];
    for (o, l) in out.iter_mut().zip(LABELS.iter()) {
        *o = match l.kind {
            LabelKind::Coulomb => model.joints()[l.index].friction.coulomb,
            LabelKind::Viscous => model.joints()[l.index].friction.viscous,
            kind => {
                let inertia = model.inertia(l.index - 1);
                match kind {
                    LabelKind::Mass => inertia.mass,
                    LabelKind::Com => inertia.com().z,
                    LabelKind::Ixx => inertia.i_com()[(0, 0)],
                    LabelKind::Iyy => inertia.i_com()[(1, 1)],
                    _ => inertia.i_com()[(2, 2)],
                }
            }
        };
    }
    Ok(out)
}

/// The full parameter vector `pi` with `tau = Y pi` (layout of [`dynforge_proto::params`]).
pub fn dynamic_parameters(model: &Model) -> Vec<f64> {
    let n = model.dof();
    let mut pi = Vec::with_capacity(num_params(n));
    for i in 0..n {
        pi.extend_from_slice(&model.inertia(i).to_params());
    }
    for j in model.joints() {
        pi.extend_from_slice(&[j.friction.coulomb, j.friction.viscous]);
    }
    pi
}

/// A copy of `model` with the dynamic parameters `pi` (e.g. identified ones); rejected if not physical.
pub fn with_dynamic_parameters(model: &Model, pi: &[f64]) -> Result<Model, ModelError> {
    let n = model.dof();
    if pi.len() != num_params(n) {
        return Err(ModelError {
            source_name: format!("model '{}'", model.name()),
            problem: ModelProblem::Config(format!("{} dynamic parameters given, {} expected", pi.len(), num_params(n))),
        });
    }
    let inertials: Vec<Inertial> = (0..n)
        .map(|i| {
            let p: [f64; NI] = pi[NI * i..NI * (i + 1)].try_into().expect("10 parameters");
            Inertial::from_spatial(&Inertia::from_params(&p))
        })
        .collect();
    let friction: Vec<Friction> =
        (0..n).map(|j| Friction { coulomb: pi[NI * n + NF * j], viscous: pi[NI * n + NF * j + 1] }).collect();
    model.with_dynamics(&inertials, &friction)
}
