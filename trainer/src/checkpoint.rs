//! A self-contained checkpoint directory: everything inference needs to turn a recording into parameters.
//!
//! ```text
//! checkpoint.json      estimator and architecture, window geometry, joint names, inputs (the transformer's feature
//!                      list; the physics estimator's parameter prior), standardisation statistics
//! model.safetensors    weights of the best validation epoch (the export format; names are module paths)
//! train/               resume state: last weights (burnpack, keeps parameter ids), optimizer state, progress
//! ```
//!
//! Every file is written atomically (temporary file, fsync, rename), so a checkpoint interrupted mid-write is the
//! previous one, whole.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::Device;
use dynforge_proto::{LABELS, NUM_LABELS};
use serde::{Deserialize, Serialize};

use dynforge_dataset::examples::ExampleRecord;
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::normalize::Standardizer;
use dynforge_dataset::split::{HoldOut, SplitRule};
use dynforge_dataset::window::WindowSpec;
use dynforge_identify::ParameterPrior;
use dynforge_robot::Model;

use crate::model::{Network, NetworkConfig};

/// Version of the checkpoint layout; readers refuse others.
pub const FORMAT: &str = "dynforge-checkpoint/2";
pub const CONFIG_FILE: &str = "checkpoint.json";
pub const WEIGHTS_FILE: &str = "model.safetensors";

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("{file}: {problem}")]
    File { file: String, problem: String },
    #[error("{0}")]
    Model(#[from] crate::model::ConfigError),
    #[error("checkpoint {checkpoint} does not fit this recording: {problem}")]
    Mismatch { checkpoint: String, problem: String },
    #[error(
        "the log's robot is not of the family the model in {checkpoint} was trained on ({problem}): `estimate` reads \
         robots of its training family. To calibrate this robot's URDF to its logs by physics, run `dynforge \
         identify LOG --urdf ROBOT.urdf`"
    )]
    OtherFamily { checkpoint: String, problem: String },
}

/// A joint of a kinematic chain as a checkpoint records it: type, placement in its parent (URDF `xyz`, `rpy`) and
/// axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointFrame {
    pub name: String,
    pub kind: String,
    pub xyz: [f64; 3],
    pub rpy: [f64; 3],
    pub axis: [f64; 3],
}

impl JointFrame {
    /// The chain of `robot`.
    pub fn chain(robot: &Model) -> Vec<JointFrame> {
        robot
            .joints()
            .iter()
            .map(|j| JointFrame {
                name: j.name.clone(),
                kind: j.kind.urdf_name().into(),
                xyz: j.origin.xyz,
                rpy: j.origin.rpy,
                axis: j.axis,
            })
            .collect()
    }

    /// How `other` differs from this joint, if it does (beyond 1e-6 m and 1e-6 rad: rounding of a file's numbers).
    fn difference(&self, other: &JointFrame) -> Option<String> {
        let placement = |f: &JointFrame| dynforge_robot::spatial::Se3::from_xyz_rpy(f.xyz, f.rpy);
        let (a, b) = (placement(self), placement(other));
        let unit = |v: [f64; 3]| nalgebra::Vector3::from(v).normalize();
        if self.kind != other.kind {
            return Some(format!("joint '{}' is {}, the family's is {}", other.name, other.kind, self.kind));
        }
        if (a.trans - b.trans).norm() > 1e-6 || (a.rot - b.rot).norm() > 1e-6 {
            return Some(format!(
                "joint '{}' sits at xyz {:?} rpy {:?}, the family's at xyz {:?} rpy {:?}",
                other.name, other.xyz, other.rpy, self.xyz, self.rpy
            ));
        }
        if (unit(self.axis) - unit(other.axis)).norm() > 1e-6 {
            return Some(format!(
                "joint '{}' turns about {:?}, the family's about {:?}",
                other.name, other.axis, self.axis
            ));
        }
        None
    }
}

fn file_error(path: &Path, problem: impl ToString) -> CheckpointError {
    CheckpointError::File { file: path.display().to_string(), problem: problem.to_string() }
}

/// Writes `bytes` to `path` atomically (see [`dynforge_proto::run_dir::write_atomic`]), creating its directory.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), CheckpointError> {
    path.parent()
        .map_or(Ok(()), std::fs::create_dir_all)
        .and_then(|()| dynforge_proto::run_dir::write_atomic(path, bytes))
        .map_err(|e| file_error(path, e))
}

/// What a checkpoint knows besides its weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    pub format: String,
    pub model: NetworkConfig,
    /// The window geometry: the transformer's input; the physics estimator's unit of the paper's protocol.
    pub window: [usize; 3],
    /// Where the windows overlap, the hop between their starts (`WindowSpec::hop`); absent: back to back.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window_hop: Option<usize>,
    /// Joint names of the robots trained on, in model order (a recording's joints are matched by these names).
    pub joints: Vec<String>,
    /// The family's kinematic chain (every robot of a generator shares it): a robot of another family is refused.
    /// Empty in checkpoints written before it was recorded.
    #[serde(default)]
    pub kinematics: Vec<JointFrame>,
    /// Jacobian feature names, in column order after q, qd, tau (transformer; empty for physics).
    pub features: Vec<String>,
    /// The generator's parameter prior the physics estimator reads evidence against (`None` for the transformer).
    #[serde(default)]
    pub prior: Option<PriorRecord>,
    /// What the physics estimator trains on besides the prior (`None` for the transformer and for checkpoints
    /// written before it was recorded): a resumed run says when it changes.
    #[serde(default)]
    pub examples: Option<ExampleRecord>,
    /// Kept input columns and their standardisation.
    pub columns: Vec<usize>,
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
    /// Label names and their standardisation.
    pub labels: Vec<String>,
    pub label_mean: Vec<f64>,
    pub label_std: Vec<f64>,
    /// The dataset trained on and its split (so evaluation sees the same validation data): what it holds out
    /// (robots for checkpoints from before splits were chosen), its seed and share.
    pub dataset: String,
    #[serde(default)]
    pub held_out: HoldOut,
    pub split_seed: u64,
    pub validation_fraction: f64,
    /// Epoch the weights come from, and its validation loss (none before the first epoch ends).
    pub epoch: usize,
    pub validation_loss: Option<f64>,
}

/// A [`ParameterPrior`] as stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PriorRecord {
    pub mean: Vec<f64>,
    /// Row-major, parameters x rank.
    pub factor: Vec<f64>,
}

impl PriorRecord {
    pub fn new(p: &ParameterPrior) -> Self {
        PriorRecord { mean: p.mean().to_vec(), factor: p.factor().to_vec() }
    }

    pub fn prior(&self) -> Option<ParameterPrior> {
        ParameterPrior::from_parts(self.mean.clone(), self.factor.clone())
    }
}

impl Checkpoint {
    /// The description of a model trained on robots of `robot`'s family.
    pub fn new(
        model: NetworkConfig,
        spec: &WindowSpec,
        robot: &Model,
        features: Option<&JacobianFeatures>,
        s: &Standardizer,
    ) -> Self {
        Checkpoint {
            format: FORMAT.into(),
            model,
            window: [spec.len, spec.stride, spec.ssr],
            window_hop: spec.overlaps().then_some(spec.hop),
            joints: robot.joints().iter().map(|j| j.name.clone()).collect(),
            kinematics: JointFrame::chain(robot),
            features: features.map_or(Vec::new(), |f| f.entries.iter().map(|e| e.name.clone()).collect()),
            prior: None,
            examples: None,
            columns: s.columns.clone(),
            mean: s.mean.clone(),
            std: s.std.clone(),
            labels: LABELS.iter().map(|l| l.name.to_string()).collect(),
            label_mean: s.label_mean.to_vec(),
            label_std: s.label_std.to_vec(),
            dataset: String::new(),
            held_out: HoldOut::Robots,
            split_seed: 0,
            validation_fraction: 0.0,
            epoch: 0,
            validation_loss: None,
        }
    }

    /// The split it was trained with.
    pub fn split_rule(&self) -> SplitRule {
        SplitRule { by: self.held_out, seed: self.split_seed, fraction: self.validation_fraction }
    }

    /// Records the split it is trained with.
    pub fn set_split(&mut self, rule: &SplitRule) {
        (self.held_out, self.split_seed, self.validation_fraction) = (rule.by, rule.seed, rule.fraction);
    }

    pub fn window_spec(&self) -> WindowSpec {
        let spec = WindowSpec::new(self.window[0], self.window[1], self.window[2]);
        spec.with_hop(self.window_hop.unwrap_or(spec.len))
    }

    pub fn standardizer(&self) -> Standardizer {
        Standardizer {
            columns: self.columns.clone(),
            mean: self.mean.clone(),
            std: self.std.clone(),
            label_mean: self.label_mean.clone().try_into().expect("checked at load"),
            label_std: self.label_std.clone().try_into().expect("checked at load"),
        }
    }

    /// The parameter prior of a physics checkpoint.
    pub fn parameter_prior(&self) -> Option<ParameterPrior> {
        self.prior.as_ref().and_then(PriorRecord::prior)
    }

    /// Refuses a recording whose robot is not of the family trained on (joints, their placements and axes) or, for
    /// the transformer, whose features differ, naming the first difference.
    pub fn check_fits(&self, dir: &Path, robot: &Model, features: &JacobianFeatures) -> Result<(), CheckpointError> {
        let checkpoint = dir.display().to_string();
        let other = |problem: String| CheckpointError::OtherFamily { checkpoint: checkpoint.clone(), problem };
        let joints: Vec<String> = robot.joints().iter().map(|j| j.name.clone()).collect();
        if joints != self.joints {
            return Err(other(format!("its joints are {joints:?}, the family's {:?}", self.joints)));
        }
        let chain = JointFrame::chain(robot);
        if let Some(d) = self.kinematics.iter().zip(&chain).find_map(|(a, b)| a.difference(b)) {
            return Err(other(d));
        }
        if matches!(self.model, NetworkConfig::Physics(_)) {
            // Physics reads the torques through the robot's own kinematics; the chain is all it must share.
            return Ok(());
        }
        let mismatch = |problem: String| CheckpointError::Mismatch { checkpoint: checkpoint.clone(), problem };
        let names: Vec<&str> = features.entries.iter().map(|e| e.name.as_str()).collect();
        if names != self.features.iter().map(String::as_str).collect::<Vec<_>>() {
            let first = names
                .iter()
                .zip(&self.features)
                .position(|(a, b)| a != b)
                .unwrap_or(names.len().min(self.features.len()));
            return Err(mismatch(format!(
                "the robot's kinematics give {} Jacobian features, the model was trained on {} (first difference at feature {first})",
                names.len(),
                self.features.len()
            )));
        }
        Ok(())
    }

    /// Writes `checkpoint.json` into `dir`.
    pub fn describe(&self, dir: &Path) -> Result<(), CheckpointError> {
        let json = serde_json::to_vec_pretty(self).map_err(|e| file_error(&dir.join(CONFIG_FILE), e))?;
        write_atomic(&dir.join(CONFIG_FILE), &json)
    }

    /// Writes the weights, then `checkpoint.json`, into `dir`.
    pub fn save(&self, dir: &Path, model: &Network) -> Result<(), CheckpointError> {
        let mut store = SafetensorsStore::from_bytes(None);
        model.save_into(&mut store).map_err(|e| file_error(&dir.join(WEIGHTS_FILE), e))?;
        let bytes = store.get_bytes().map_err(|e| file_error(&dir.join(WEIGHTS_FILE), e))?;
        let bytes = canonical_safetensors(&bytes).ok_or_else(|| file_error(&dir.join(WEIGHTS_FILE), "unreadable"))?;
        write_atomic(&dir.join(WEIGHTS_FILE), &bytes)?;
        self.describe(dir)
    }

    /// Reads the description of the checkpoint in `dir`.
    pub fn read(dir: &Path) -> Result<Checkpoint, CheckpointError> {
        let path = dir.join(CONFIG_FILE);
        let text = std::fs::read(&path).map_err(|e| {
            file_error(
                &path,
                if e.kind() == std::io::ErrorKind::NotFound {
                    "not a checkpoint (no checkpoint.json)".into()
                } else {
                    e.to_string()
                },
            )
        })?;
        let c: Checkpoint = serde_json::from_slice(&text).map_err(|e| file_error(&path, e))?;
        if c.format != FORMAT {
            return Err(file_error(&path, format!("format {:?}, this dynforge reads {FORMAT:?}", c.format)));
        }
        let names: Vec<&str> = LABELS.iter().map(|l| l.name).collect();
        if c.labels != names || c.label_mean.len() != NUM_LABELS || c.label_std.len() != NUM_LABELS {
            return Err(file_error(&path, "its labels are not this dynforge's 38 labels"));
        }
        let inputs = match &c.model {
            NetworkConfig::Transformer(m) => m.seq_len == c.window[0] && m.inputs == c.columns.len(),
            NetworkConfig::Physics(m) => {
                c.parameter_prior().is_some_and(|p| dynforge_dataset::evidence::feature_width(p.rank()) == m.inputs)
                    && m.inputs == c.columns.len()
            }
        };
        if !(inputs && c.columns.len() == c.mean.len() && c.columns.len() == c.std.len()) {
            return Err(file_error(&path, "inconsistent columns, statistics, prior and model inputs"));
        }
        let spec = c.window_spec();
        if !spec.is_valid() {
            let problem = format!(
                "window {}:{}:{} with hop {}: not positive, or the hop does not divide {}",
                spec.len, spec.stride, spec.ssr, spec.hop, spec.len
            );
            return Err(file_error(&path, problem));
        }
        c.model.check()?;
        Ok(c)
    }

    /// Reads a checkpoint and its weights.
    pub fn load(dir: &Path, device: &Device) -> Result<(Checkpoint, Network), CheckpointError> {
        let c = Checkpoint::read(dir)?;
        let path: PathBuf = dir.join(WEIGHTS_FILE);
        let bytes = std::fs::read(&path).map_err(|e| file_error(&path, e))?;
        let mut model = c.model.init(device)?;
        let mut store = SafetensorsStore::from_bytes(Some(bytes));
        let result = model.load_from(&mut store).map_err(|e| file_error(&path, e))?;
        if !result.missing.is_empty() || !result.errors.is_empty() {
            return Err(file_error(&path, format!("weights do not fit the architecture: {result}")));
        }
        Ok((c, model.valid()))
    }
}

/// `bytes` (a safetensors file) with its tensors laid out in name order. The store writes them in the order of a
/// hash map, which changes from run to run: the same weights must give the same file.
fn canonical_safetensors(bytes: &[u8]) -> Option<Vec<u8>> {
    let n = usize::try_from(u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?)).ok()?;
    let header: serde_json::Map<String, serde_json::Value> = serde_json::from_slice(bytes.get(8..8 + n)?).ok()?;
    let data = &bytes[8 + n..];
    let mut tensors: Vec<(String, serde_json::Value)> = header.into_iter().collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    let (mut out_header, mut out_data) = (serde_json::Map::new(), Vec::with_capacity(data.len()));
    for (name, mut info) in tensors {
        if name != "__metadata__" {
            let range = info.get("data_offsets")?.as_array()?;
            let (a, b) = (range.first()?.as_u64()? as usize, range.get(1)?.as_u64()? as usize);
            let start = out_data.len();
            out_data.extend_from_slice(data.get(a..b)?);
            info["data_offsets"] = serde_json::json!([start, out_data.len()]);
        }
        out_header.insert(name, info);
    }
    let mut text = serde_json::to_vec(&out_header).ok()?;
    // The data start 8-byte aligned.
    text.resize(text.len().next_multiple_of(8), b' ');
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend(out_data);
    Some(out)
}
