//! The generator's configuration: the fixed kinematics and the ranges robots are drawn from. A contract: it is part
//! of every run manifest, and the same configuration, seed and [`GENERATOR_VERSION`] give the same robots.
//!
//! Loadable from TOML (every field optional, defaults below), so users can widen or narrow the distribution to
//! bracket their own robot. The generator itself (geometry to inertia) is `dynforge_robot::generator`.

use serde::{Deserialize, Serialize};

/// Version of the generation procedure, recorded with datasets: bump it whenever the same (seed, id) would give a
/// different robot.
pub const GENERATOR_VERSION: u32 = 1;

/// Link cross-section shapes. `D` is the outer diameter (circle, tube) or the width across flats (square, hexagon).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SectionKind {
    Solid,
    Tube,
    Square,
    Hexagon,
}

impl SectionKind {
    pub const ALL: [SectionKind; 4] =
        [SectionKind::Solid, SectionKind::Tube, SectionKind::Square, SectionKind::Hexagon];
}

/// A closed range `[lo, hi]` drawn uniformly.
pub type Range = [f64; 2];

/// The fixed 6R kinematic configuration shared by every generated robot ("df6").
///
/// A UR5-like arm with in-line links so that each link is one straight beam: joint 0 (shoulder pan, z) sits on a
/// pedestal; joints 1-3 (shoulder lift, elbow, wrist 1) turn about y; joint 4 (wrist 2) about z; joint 5 (wrist 3)
/// about y. At q = 0 the arm points straight up. Link `k` spans from joint `k-1` to joint `k` along its z axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Kinematics {
    /// Height of joint 0 above the ground / base frame [m].
    pub pedestal_height: f64,
    /// Pedestal diameter [m] (visual and collision only: the base is fixed).
    pub pedestal_diameter: f64,
    /// Length of links 1-6 [m]; the last one is the flange/tool stub.
    pub link_lengths: [f64; 6],
    /// Nominal link diameters [m]; each robot scales them by `diameter_scale`.
    pub nominal_diameters: [f64; 6],
    /// Joint axes in the joint frames.
    pub axes: [[f64; 3]; 6],
    /// Position limits [rad] (lower, upper).
    pub position_limits: [Range; 6],
    /// Actuator torque limits [N m].
    pub effort: [f64; 6],
    /// Joint speed limits [rad/s].
    pub velocity: [f64; 6],
}

impl Default for Kinematics {
    fn default() -> Self {
        use std::f64::consts::PI;
        Kinematics {
            pedestal_height: 0.10,
            pedestal_diameter: 0.16,
            link_lengths: [0.12, 0.425, 0.392, 0.10, 0.10, 0.08],
            nominal_diameters: [0.12, 0.09, 0.075, 0.065, 0.065, 0.06],
            axes: [
                [0.0, 0.0, 1.0],
                [0.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [0.0, 1.0, 0.0],
            ],
            position_limits: [[-PI, PI], [-2.0, 2.0], [-2.6, 2.6], [-2.6, 2.6], [-PI, PI], [-PI, PI]],
            effort: [330.0, 330.0, 150.0, 56.0, 56.0, 56.0],
            velocity: [2.0, 2.0, 3.0, 3.0, 3.0, 3.0],
        }
    }
}

/// Everything that varies between robots, and how.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GeneratorConfig {
    pub kinematics: Kinematics,
    /// Mean material density [kg/m^3] (aluminium).
    pub density: f64,
    /// Cross-sections drawn from, uniformly, independently per link.
    pub sections: Vec<SectionKind>,
    /// Factor on each link's nominal diameter.
    pub diameter_scale: Range,
    /// Tube wall thickness as a fraction of the outer diameter (must stay below 0.5).
    pub tube_wall_fraction: Range,
    /// Linear density gradient `g` along each link: COM at `L (1/2 + g/6)`; must stay inside (-1, 1).
    pub density_gradient: Range,
    /// Coulomb friction torque per joint [N m].
    pub coulomb: [Range; 6],
    /// Viscous friction per joint [N m s/rad].
    pub viscous: [Range; 6],
}

impl Default for GeneratorConfig {
    fn default() -> Self {
        GeneratorConfig {
            kinematics: Kinematics::default(),
            density: 2700.0,
            sections: SectionKind::ALL.to_vec(),
            diameter_scale: [0.7, 1.3],
            tube_wall_fraction: [0.08, 0.25],
            density_gradient: [-0.8, 0.8],
            coulomb: [[0.5, 4.0], [0.5, 4.0], [0.3, 3.0], [0.1, 1.0], [0.1, 1.0], [0.1, 1.0]],
            viscous: [[0.2, 3.0], [0.2, 3.0], [0.1, 2.0], [0.02, 0.5], [0.02, 0.5], [0.02, 0.5]],
        }
    }
}

/// A configuration that cannot produce valid robots.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("generator config: {0}")]
pub struct ConfigError(pub String);

impl GeneratorConfig {
    /// Parses a TOML configuration (missing fields take their defaults) and validates it.
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        let c: GeneratorConfig = toml::from_str(text).map_err(|e| ConfigError(e.to_string()))?;
        c.validate()?;
        Ok(c)
    }

    /// The configuration in the TOML file `path`, or the default one without a file; errors name the file.
    pub fn load(path: Option<&std::path::Path>) -> Result<Self, ConfigError> {
        let Some(path) = path else { return Ok(GeneratorConfig::default()) };
        let text =
            std::fs::read_to_string(path).map_err(|e| ConfigError(format!("reading {}: {e}", path.display())))?;
        GeneratorConfig::from_toml(&text).map_err(|e| ConfigError(format!("in {}: {}", path.display(), e.0)))
    }

    /// Checks every range can only produce physical robots.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |m: String| Err(ConfigError(m));
        let ordered = |name: &str, r: &Range, min: f64, max: f64| -> Result<(), ConfigError> {
            if !(r[0] <= r[1] && r[0] >= min && r[1] <= max && r[0].is_finite() && r[1].is_finite()) {
                // Bounds that only exclude what no range may hold are said in words, not as 309-digit numbers.
                let within = match (min, max) {
                    (f64::MIN, f64::MAX) => "of finite numbers".to_string(),
                    (f64::MIN_POSITIVE, f64::MAX) => "of positive numbers".to_string(),
                    (0.0, f64::MAX) => "of non-negative numbers".to_string(),
                    (f64::MIN_POSITIVE, hi) => format!("within (0, {hi}]"),
                    (lo, hi) => format!("within [{lo}, {hi}]"),
                };
                return Err(ConfigError(format!("{name} = {r:?} must be an ordered range {within}")));
            }
            Ok(())
        };
        if self.sections.is_empty() {
            return bad("sections must list at least one cross-section".into());
        }
        if !(self.density > 0.0 && self.density.is_finite()) {
            return bad(format!("density {} must be positive", self.density));
        }
        ordered("diameter_scale", &self.diameter_scale, f64::MIN_POSITIVE, f64::MAX)?;
        ordered("tube_wall_fraction", &self.tube_wall_fraction, f64::MIN_POSITIVE, 0.499)?;
        ordered("density_gradient", &self.density_gradient, -0.99, 0.99)?;
        for j in 0..6 {
            ordered(&format!("coulomb[{j}]"), &self.coulomb[j], 0.0, f64::MAX)?;
            ordered(&format!("viscous[{j}]"), &self.viscous[j], 0.0, f64::MAX)?;
            let k = &self.kinematics;
            ordered(&format!("kinematics.position_limits[{j}]"), &k.position_limits[j], f64::MIN, f64::MAX)?;
            if !(k.link_lengths[j] > 0.0 && k.nominal_diameters[j] > 0.0 && k.effort[j] > 0.0 && k.velocity[j] > 0.0) {
                return bad(format!(
                    "kinematics of link/joint {j}: lengths, diameters, effort and velocity must be positive"
                ));
            }
            // A joint turns about a direction: a zero (or non-finite) axis has none, and every job would fail.
            let axis = k.axes[j];
            let norm = axis.iter().map(|a| a * a).sum::<f64>().sqrt();
            if !(norm > 1e-9 && norm.is_finite()) {
                return bad(format!("kinematics.axes[{j}] = {axis:?} is not a direction (zero or not finite)"));
            }
        }
        Ok(())
    }
}
