//! The torque check: how well parameter sets predict recordings' torques by inverse dynamics.
//!
//! For every sample, `tau_hat = Y(q, qd, qdd) pi` (RNEA plus friction) with `qdd` by central differences of `qd` on
//! the 1 kHz grid, against the recorded (applied) torque; a joint's samples at rest are left out (static Coulomb
//! friction takes any value in `[-mu_c, mu_c]`). NRMSE per joint = RMSE / standard deviation of the recorded torque
//! over the same samples; the overall value is the mean over joints. The sums live in `dynforge_identify`'s normal
//! equations, so one pass over a recording scores any number of parameter sets.

use dynforge_identify::TorqueError;
use serde::{Deserialize, Serialize};

/// Held-out torque NRMSE of one parameter set.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TorqueRow {
    pub parameters: String,
    /// Per joint (NaN for a joint that never moved).
    pub per_joint: Vec<f64>,
    pub overall: f64,
}

impl TorqueRow {
    pub fn new(parameters: &str, e: &TorqueError) -> Self {
        TorqueRow { parameters: parameters.into(), per_joint: e.per_joint(), overall: e.overall() }
    }
}

/// Markdown table of torque rows.
pub fn table(rows: &[TorqueRow]) -> String {
    let joints = rows.first().map_or(0, |r| r.per_joint.len());
    let mut out = format!(
        "| parameters |{} overall |\n|---|{}---:|\n",
        (0..joints).map(|j| format!(" J{j} |")).collect::<String>(),
        "---:|".repeat(joints)
    );
    for r in rows {
        out.push_str(&format!(
            "| {} |{} {:.4} |\n",
            r.parameters,
            r.per_joint.iter().map(|x| format!(" {x:.4} |")).collect::<String>(),
            r.overall
        ));
    }
    out
}
