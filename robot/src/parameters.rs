//! Views of a model as parameter vectors: the 38 paper labels and the full `12 n` dynamic-parameter vector.

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI, num_params};
use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};

use crate::model::{Friction, Inertial, Model, ModelError, ModelProblem};
use crate::spatial::Inertia;

/// The paper's 38 labels (order of [`dynforge_proto::LABELS`]). Needs a 6-joint model.
pub fn labels_of(model: &Model) -> Result<[f64; NUM_LABELS], ModelError> {
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
            kind => link_label(kind, model.inertia(l.index - 1)),
        };
    }
    Ok(out)
}

/// A link label of kind `kind` (mass, COM along the link axis, or a moment about the COM) of the link `inertia`;
/// NaN for the friction kinds, which belong to joints.
pub fn link_label(kind: LabelKind, inertia: &Inertia) -> f64 {
    match kind {
        LabelKind::Mass => inertia.mass,
        LabelKind::Com => inertia.com().z,
        LabelKind::Ixx => inertia.i_com()[(0, 0)],
        LabelKind::Iyy => inertia.i_com()[(1, 1)],
        LabelKind::Izz => inertia.i_com()[(2, 2)],
        LabelKind::Coulomb | LabelKind::Viscous => f64::NAN,
    }
}

/// Names of a robot's standard parameters, in [`standard_parameters`]' order: per link `LINK.mass`, `LINK.com_x`
/// .. `LINK.com_z`, `LINK.ixx`, `LINK.ixy`, `LINK.ixz`, `LINK.iyy`, `LINK.iyz`, `LINK.izz`, then per joint
/// `JOINT.coulomb`, `JOINT.viscous`: the labels of any serial arm, as `identify` reports them.
pub fn standard_names(model: &Model) -> Vec<String> {
    const LINK: [&str; 10] = ["mass", "com_x", "com_y", "com_z", "ixx", "ixy", "ixz", "iyy", "iyz", "izz"];
    let links = model.links().iter().flat_map(|l| LINK.map(|k| format!("{}.{k}", l.name)));
    let joints = model.joints().iter().flat_map(|j| ["coulomb", "viscous"].map(|k| format!("{}.{k}", j.name)));
    links.chain(joints).collect()
}

/// A robot's standard parameters: per link its mass [kg], centre of mass [m] and inertia about the centre of mass
/// [kg m^2] in the link's frame, per joint its Coulomb and viscous friction.
pub fn standard_parameters(model: &Model) -> Vec<f64> {
    let mut out = Vec::with_capacity(10 * model.dof() + 2 * model.dof());
    for l in 0..model.dof() {
        let inertia = model.inertia(l);
        let (c, i) = (inertia.com(), inertia.i_com());
        out.extend([inertia.mass, c.x, c.y, c.z, i[(0, 0)], i[(0, 1)], i[(0, 2)], i[(1, 1)], i[(1, 2)], i[(2, 2)]]);
    }
    for j in model.joints() {
        out.extend([j.friction.coulomb, j.friction.viscous]);
    }
    out
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

/// Smallest mass [kg] and principal moment [kg m^2] an estimate is projected up to.
const MIN_MASS: f64 = 1e-3;
const MIN_MOMENT: f64 = 1e-7;
/// A moment projected onto the triangle inequality lands this fraction inside it, not on it: written in decimal and
/// read back, a moment exactly equal to the sum of the other two can come out above it by a rounding, and loaders
/// (MuJoCo) refuse such a body.
pub const TRIANGLE_MARGIN: f64 = 1e-6;

/// A copy of the 6-joint `model` carrying the 38 labels `y` (e.g. a network's estimate). What the labels do not
/// cover is kept from `model`: the COM's x and y, products of inertia, and link 1's mass, COM and Ixx, Iyy (which
/// never enter its dynamics; they grow if link 1's Izz needs it). Values outside physics are projected back (friction >= 0, mass and moments
/// positive, each moment at most the sum of the other two); every projection is described in the returned list.
pub fn model_with_labels(model: &Model, y: &[f64; NUM_LABELS]) -> Result<(Model, Vec<String>), ModelError> {
    labels_of(model)?; // the 6-joint check, with its error
    let mut notes = Vec::new();
    let mut floor = |name: &str, v: f64, min: f64, unit: &str| {
        if v < min || !v.is_finite() {
            notes.push(format!("{name} = {v:.4e} {unit} raised to {min:e}"));
            min
        } else {
            v
        }
    };
    let n = model.dof();
    let mut mass: Vec<f64> = (0..n).map(|i| model.inertia(i).mass).collect();
    let mut com: Vec<_> = (0..n).map(|i| model.inertia(i).com()).collect();
    let mut i_com: Vec<_> = (0..n).map(|i| model.inertia(i).i_com()).collect();
    let mut friction: Vec<Friction> = model.joints().iter().map(|j| j.friction).collect();
    for (l, &v) in LABELS.iter().zip(y.iter()) {
        let link = l.index.wrapping_sub(1);
        match l.kind {
            LabelKind::Coulomb => friction[l.index].coulomb = floor(l.name, v, 0.0, l.kind.unit()),
            LabelKind::Viscous => friction[l.index].viscous = floor(l.name, v, 0.0, l.kind.unit()),
            LabelKind::Mass => mass[link] = floor(l.name, v, MIN_MASS, l.kind.unit()),
            LabelKind::Com => com[link].z = v,
            LabelKind::Ixx => i_com[link][(0, 0)] = floor(l.name, v, MIN_MOMENT, l.kind.unit()),
            LabelKind::Iyy => i_com[link][(1, 1)] = floor(l.name, v, MIN_MOMENT, l.kind.unit()),
            LabelKind::Izz => i_com[link][(2, 2)] = floor(l.name, v, MIN_MOMENT, l.kind.unit()),
        }
    }
    // Link 1 carries only Izz: its unlabelled Ixx, Iyy (no effect on the dynamics) grow to keep it physical.
    let i1 = &mut i_com[0];
    let (sum, izz) = (i1[(0, 0)] + i1[(1, 1)], i1[(2, 2)]);
    if izz > sum * (1.0 - TRIANGLE_MARGIN) {
        let scale = izz / (sum * (1.0 - 2.0 * TRIANGLE_MARGIN));
        i1[(0, 0)] *= scale;
        i1[(1, 1)] *= scale;
    }
    // With the moments sorted a >= b >= c only a <= b + c can fail. Lowering a onto b + c (less the margin) keeps
    // it the largest unless c is tiny next to b, so a near-zero c is first raised to 2 b x margin.
    for (link, i) in i_com.iter_mut().enumerate() {
        let mut axes = [0, 1, 2];
        axes.sort_by(|&p, &q| i[(q, q)].total_cmp(&i[(p, p)]));
        let [a, b, c] = axes;
        let name = |axis: usize| format!("{}_l{}", ["ixx", "iyy", "izz"][axis], link + 1);
        if i[(c, c)] < 2.0 * TRIANGLE_MARGIN * i[(b, b)] {
            let raised = 2.0 * TRIANGLE_MARGIN * i[(b, b)];
            notes.push(format!(
                "{} = {:.4e} kg m^2 raised to {raised:.4e} so that link {} can satisfy the triangle inequality",
                name(c),
                i[(c, c)],
                link + 1
            ));
            i[(c, c)] = raised;
        }
        let others = (i[(b, b)] + i[(c, c)]) * (1.0 - TRIANGLE_MARGIN);
        if i[(a, a)] > others {
            notes.push(format!(
                "{} = {:.4e} kg m^2 lowered to {others:.4e}, just inside the sum of the other two moments of link {} \
                 (triangle inequality)",
                name(a),
                i[(a, a)],
                link + 1
            ));
            i[(a, a)] = others;
        }
    }
    let inertials: Vec<Inertial> =
        (0..n).map(|i| Inertial::from_spatial(&Inertia::from_com(mass[i], com[i], i_com[i]))).collect();
    Ok((model.with_dynamics(&inertials, &friction)?, notes))
}
