//! A robot's family as a dataset's source: variants of one URDF (its kinematics and limits; its inertial parameters
//! and friction drawn around the URDF's), each simulated on the excitations `dynforge excite` designed for it. The
//! run directory keeps its own copy of the URDF and the excitations (`family/`), so workers on any host read the same
//! bytes; the manifest keeps their hashes, so a resume with other files is refused.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::content_hash_hex;
use crate::fourier::Excitation;
use crate::spread::Spread;

/// The run directory's family folder, and its URDF.
pub const DIR: &str = "family";
pub const URDF: &str = "robot.urdf";

/// The file of excitation `k`, as `dynforge excite` names it.
pub fn excitation_file(k: usize) -> String {
    format!("excitation-{k}.json")
}

/// The manifest of an excitation directory, written last by `dynforge excite`: the set's size and each member's
/// hash. A directory without it is one whose writing was interrupted (or an `excite` older than it), and a member
/// that differs from its hash, or one past the count, is not of the set.
pub const SET: &str = "excitation-set.json";

/// An excitation directory's manifest ([`SET`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExcitationSet {
    /// FNV-1a of each `excitation-K.json`'s bytes, in hex, in order.
    pub hashes: Vec<String>,
}

impl ExcitationSet {
    /// The manifest of the excitations whose JSON texts are `texts` (in order).
    pub fn of(texts: &[String]) -> Self {
        ExcitationSet { hashes: texts.iter().map(|t| content_hash_hex(t.as_bytes())).collect() }
    }
}

/// Relative spread of the drawn variants around the URDF's values: masses and the inertia tensors' scales
/// log-normally and independently, the tensors' shapes within half of that, centres of mass in proportion to their
/// distance from the link's origin (as `identify`'s prior reads a URDF).
pub const DEFAULT_SPREAD: f64 = 0.3;

/// The family of a run, as its manifest records it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Family {
    /// FNV-1a of the URDF's bytes and of each excitation file's, in hex.
    pub urdf_hash: String,
    pub excitation_hashes: Vec<String>,
    /// Joints welded at a position (`--fix NAME=POS`), as the excitations were designed.
    pub welds: BTreeMap<String, f64>,
    /// Relative spread of the inertial parameters and friction, per kind ([`DEFAULT_SPREAD`] for all by default).
    pub spread: Spread,
    /// Revision of the prior the variants are drawn from (`identify`'s `CoordinatePrior`): a family made under
    /// another draws other robots, so a resume under this one is refused. Manifests that name none had the first.
    #[serde(default = "first_prior")]
    pub prior: u32,
}

/// The prior's revision: 3 draws a friction the URDF states less of within a typical one sized from the joint's
/// effort and speed limits (2 within 2 % of the effort limit); 2 draws mass, the inertia tensor's scale and its shape
/// independently (1 drew the principal radii independently of the mass, and the centre of mass in proportion to the
/// link's size).
pub const PRIOR_REVISION: u32 = 3;

fn first_prior() -> u32 {
    1
}

/// Why a family's files cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum FamilyError {
    #[error("{file}: {message}")]
    File { file: String, message: String },
}

/// The text of `path`, or an error naming it.
fn read_text(path: &Path) -> Result<String, FamilyError> {
    std::fs::read_to_string(path)
        .map_err(|e| FamilyError::File { file: path.display().to_string(), message: e.to_string() })
}

/// A family's files: the URDF's text and the excitations' (as read, so hashes and copies are of the same bytes).
#[derive(Debug, Clone)]
pub struct Sources {
    pub urdf: String,
    pub excitations: Vec<String>,
}

impl Sources {
    /// The URDF and the excitations of `dir` (`excitation-0.json`, `excitation-1.json`, ... as `dynforge excite`
    /// writes them, as many as its manifest [`SET`] lists, each with the hash it lists), each parsed once to name a
    /// bad file now rather than in every worker.
    pub fn read(urdf: &Path, dir: &Path) -> Result<Self, FamilyError> {
        let urdf = read_text(urdf)?;
        let manifest = dir.join(SET);
        let rerun = "rerun `dynforge excite` into it";
        if !manifest.exists() {
            let message = match dir.join(excitation_file(0)).exists() {
                true => {
                    format!("no {SET}: its writing was interrupted, or an older `dynforge excite` wrote it; {rerun}")
                }
                false => format!("no {} (write one with `dynforge excite`)", excitation_file(0)),
            };
            return Err(FamilyError::File { file: dir.display().to_string(), message });
        }
        let set: ExcitationSet = serde_json::from_str(&read_text(&manifest)?).map_err(|e| FamilyError::File {
            file: manifest.display().to_string(),
            message: format!("not an excitation set's manifest: {e}"),
        })?;
        if set.hashes.is_empty() {
            return Err(FamilyError::File {
                file: manifest.display().to_string(),
                message: "lists no excitation".into(),
            });
        }
        let mut excitations = Vec::new();
        for (k, hash) in set.hashes.iter().enumerate() {
            let path = dir.join(excitation_file(k));
            let text = read_text(&path)?;
            if content_hash_hex(text.as_bytes()) != *hash {
                return Err(FamilyError::File {
                    file: path.display().to_string(),
                    message: format!(
                        "differs from the excitation {SET} lists (changed since `excite` wrote it); {rerun}"
                    ),
                });
            }
            parse_excitation(&text, &path.display().to_string())?;
            excitations.push(text);
        }
        Ok(Sources { urdf, excitations })
    }

    /// The manifest's record of these files.
    pub fn family(&self, welds: BTreeMap<String, f64>, spread: Spread) -> Family {
        Family {
            urdf_hash: content_hash_hex(self.urdf.as_bytes()),
            excitation_hashes: self.excitations.iter().map(|e| content_hash_hex(e.as_bytes())).collect(),
            welds,
            spread,
            prior: PRIOR_REVISION,
        }
    }

    /// Copies the files into the run directory `run` (`family/`), each written atomically.
    pub fn write_to(&self, run: &Path) -> std::io::Result<()> {
        let dir = run.join(DIR);
        std::fs::create_dir_all(&dir)?;
        crate::run_dir::write_atomic(&dir.join(URDF), self.urdf.as_bytes())?;
        for (k, text) in self.excitations.iter().enumerate() {
            crate::run_dir::write_atomic(&dir.join(excitation_file(k)), text.as_bytes())?;
        }
        Ok(())
    }

    /// The copies in the run directory `run`, checked against the manifest's hashes.
    pub fn of_run(run: &Path, family: &Family) -> Result<Self, FamilyError> {
        let dir = run.join(DIR);
        let read = |name: &str, hash: &str| {
            let path = dir.join(name);
            let text = read_text(&path)?;
            match content_hash_hex(text.as_bytes()) == hash {
                true => Ok(text),
                false => Err(FamilyError::File {
                    file: path.display().to_string(),
                    message: "differs from the file the run's manifest names (its hash)".into(),
                }),
            }
        };
        let urdf = read(URDF, &family.urdf_hash)?;
        let excitations = (family.excitation_hashes.iter().enumerate())
            .map(|(k, h)| read(&excitation_file(k), h))
            .collect::<Result<_, _>>()?;
        Ok(Sources { urdf, excitations })
    }

    /// The excitations, parsed.
    pub fn parsed(&self) -> Result<Vec<Excitation>, FamilyError> {
        (self.excitations.iter().enumerate()).map(|(k, text)| parse_excitation(text, &excitation_file(k))).collect()
    }
}

fn parse_excitation(text: &str, file: &str) -> Result<Excitation, FamilyError> {
    let e: Excitation = serde_json::from_str(text)
        .map_err(|e| FamilyError::File { file: file.to_string(), message: format!("not an excitation: {e}") })?;
    let s = &e.series;
    let consistent = s.joints() == e.joints.len()
        && s.a.len() == s.joints()
        && s.b.len() == s.joints()
        && s.a.iter().zip(&s.b).all(|(a, b)| a.len() == b.len())
        && s.period.is_finite()
        && s.period > 0.0;
    match consistent {
        true => Ok(e),
        false => Err(FamilyError::File {
            file: file.to_string(),
            message: "an excitation needs one start value and one row of a and b coefficients per joint, and a \
                      positive period"
                .into(),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An excitation directory is read through its manifest: as many members as it lists, each with its hash; one
    /// without a manifest (an interrupted write) or with a member changed since is refused, naming the file.
    #[test]
    fn an_excitation_set_is_read_through_its_manifest() {
        let tmp = tempfile::tempdir().expect("a temporary directory");
        let (dir, urdf) = (tmp.path(), tmp.path().join("robot.urdf"));
        std::fs::write(&urdf, "<robot name=\"r\"/>").unwrap();
        let member = |k: usize| {
            format!(
                r#"{{"joints": ["a"], "series": {{"period": {}, "start": [0.0], "a": [[0.1]], "b": [[0.0]]}}}}"#,
                k + 1
            )
        };
        let texts: Vec<String> = (0..3).map(member).collect();
        for (k, t) in texts.iter().enumerate() {
            std::fs::write(dir.join(excitation_file(k)), t).unwrap();
        }
        let refused = |why: &str| {
            let e = Sources::read(&urdf, dir).expect_err("refused").to_string();
            assert!(e.contains(why), "{e}");
        };
        refused("no excitation-set.json: its writing was interrupted");
        // A manifest of the first two: the third, left by an earlier set, is not read.
        let set = serde_json::to_string(&ExcitationSet::of(&texts[..2])).unwrap();
        std::fs::write(dir.join(SET), set).unwrap();
        let read = Sources::read(&urdf, dir).expect("a set of two");
        assert_eq!(read.excitations, texts[..2]);
        std::fs::write(dir.join(excitation_file(1)), member(7)).unwrap();
        refused("excitation-1.json: differs from the excitation excitation-set.json lists");
    }

    /// A manifest written before the prior's revision was recorded reads as the first prior, so resuming it under
    /// this one is refused as another run rather than mixing two distributions of robots.
    #[test]
    fn a_family_recorded_without_a_prior_revision_is_the_first() {
        let old = r#"{"urdf_hash": "00", "excitation_hashes": ["01"], "welds": {}, "spread": 0.3}"#;
        let family: Family = serde_json::from_str(old).expect("an old record parses");
        assert_eq!(family.prior, 1);
        let now = Family { prior: PRIOR_REVISION, ..family.clone() };
        assert_ne!(family, now);
    }
}
