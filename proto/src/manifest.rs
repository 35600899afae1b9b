//! The run manifest: everything that determines a dataset's content, written once into the output directory. A
//! later `generate` on the same directory resumes only if its manifest is identical, so a dataset never mixes
//! shards of two configurations. The one allowed change is more robots: jobs, their ids and partitions are per
//! robot, so the shards already written are exactly those a run of the larger size would write.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::family::Family;
use crate::generator::{GENERATOR_VERSION, GeneratorConfig};
use crate::sim::SimConfig;

pub const FILE: &str = crate::run_dir::MANIFEST;

/// `i/n`: a host runs the robots `r` with `r % n == i`. The union of `0/n .. (n-1)/n` is the whole run, and
/// partitions never share a robot (so they never share a shard).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Partition {
    pub index: u32,
    pub count: u32,
}

impl Partition {
    pub const WHOLE: Partition = Partition { index: 0, count: 1 };

    pub fn contains(&self, robot: u64) -> bool {
        robot % self.count as u64 == self.index as u64
    }
}

impl fmt::Display for Partition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// A partition flag that is not `i/n` with `0 <= i < n`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("partition '{text}': {problem}")]
pub struct PartitionError {
    pub text: String,
    pub problem: String,
}

impl FromStr for Partition {
    type Err = PartitionError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = |problem: String| PartitionError { text: s.to_string(), problem };
        let (i, n) = s.split_once('/').ok_or_else(|| bad("is not of the form i/n".into()))?;
        let index: u32 = i.trim().parse().map_err(|_| bad(format!("'{i}' is not a number")))?;
        let count: u32 = n.trim().parse().map_err(|_| bad(format!("'{n}' is not a number")))?;
        if count == 0 || index >= count {
            return Err(bad("i must be in 0..n (n > 0)".into()));
        }
        Ok(Partition { index, count })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub dynforge_version: String,
    pub generator_version: u32,
    pub shard_version: u32,
    pub seed: u64,
    pub robots: u64,
    pub trajectories: u32,
    pub partition: Partition,
    pub generator: GeneratorConfig,
    pub sim: SimConfig,
    /// A robot's family instead of the generator's robots (`generate --urdf`): what its variants are drawn around.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub family: Option<Family>,
}

#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    #[error("{path}: {message}")]
    Io { path: String, message: String },
    #[error("{path}: not a dynforge run manifest: {message}")]
    Parse { path: String, message: String },
    #[error(
        "{path} describes a different run ({differences}); resume with the same settings, or use another --out directory"
    )]
    Mismatch { path: String, differences: String },
}

impl Manifest {
    pub fn new(
        seed: u64,
        robots: u64,
        trajectories: u32,
        partition: Partition,
        generator: GeneratorConfig,
        sim: SimConfig,
    ) -> Self {
        Manifest {
            dynforge_version: env!("CARGO_PKG_VERSION").to_string(),
            generator_version: GENERATOR_VERSION,
            shard_version: crate::shard::SHARD_VERSION,
            seed,
            robots,
            trajectories,
            partition,
            generator,
            sim,
            family: None,
        }
    }

    /// The same run with the robots of `family`.
    pub fn with_family(self, family: Option<Family>) -> Self {
        Manifest { family, ..self }
    }

    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("a manifest serialises")
    }

    /// Reads `DIR/manifest.toml`, if present.
    pub fn load(dir: &Path) -> Result<Option<Manifest>, ManifestError> {
        let path = dir.join(FILE);
        let shown = path.display().to_string();
        match std::fs::read_to_string(&path) {
            Ok(text) => toml::from_str(&text)
                .map(Some)
                .map_err(|e| ManifestError::Parse { path: shown, message: e.to_string() }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(ManifestError::Io { path: shown, message: e.to_string() }),
        }
    }

    /// Writes the manifest into a new run directory, or checks it against the one already there. Returns the
    /// directory's previous robot count when this run grows it.
    pub fn create_or_check(&self, dir: &Path) -> Result<Option<u64>, ManifestError> {
        let path = dir.join(FILE);
        let shown = path.display().to_string();
        let mut grown = None;
        if let Some(existing) = Manifest::load(dir)? {
            if existing == *self {
                return Ok(None);
            }
            if self.robots <= existing.robots || (Manifest { robots: self.robots, ..existing.clone() }) != *self {
                let mut differences = self.differences(&existing);
                if self.robots < existing.robots {
                    differences.push_str(" (a dataset can grow, not shrink)");
                }
                return Err(ManifestError::Mismatch { path: shown, differences });
            }
            grown = Some(existing.robots);
        }
        crate::run_dir::write_atomic(&path, self.to_toml().as_bytes())
            .map_err(|e| ManifestError::Io { path: shown, message: e.to_string() })?;
        Ok(grown)
    }

    /// The settings that differ, by their dotted names (`sim.dt`), each with both values.
    fn differences(&self, other: &Manifest) -> String {
        let a: toml::Table = toml::from_str(&self.to_toml()).expect("round trip");
        let b: toml::Table = toml::from_str(&other.to_toml()).expect("round trip");
        let mut out = Vec::new();
        table_differences("", &a, &b, &mut out);
        out.join("; ")
    }
}

fn table_differences(prefix: &str, a: &toml::Table, b: &toml::Table, out: &mut Vec<String>) {
    for (key, va) in a {
        let name = format!("{prefix}{key}");
        match (va, b.get(key)) {
            (_, Some(vb)) if vb == va => {}
            (toml::Value::Table(ta), Some(toml::Value::Table(tb))) => {
                table_differences(&format!("{name}."), ta, tb, out)
            }
            (_, Some(vb)) => out.push(format!("{name}: requested {va}, directory has {vb}")),
            (_, None) => out.push(format!("{name} missing in the directory's manifest")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest(robots: u64) -> Manifest {
        Manifest::new(1, robots, 16, Partition::WHOLE, GeneratorConfig::default(), SimConfig::default())
    }

    #[test]
    fn same_manifest_resumes_and_a_different_one_is_refused_with_the_difference() {
        let dir = tempfile::tempdir().unwrap();
        manifest(8).create_or_check(dir.path()).unwrap();
        manifest(8).create_or_check(dir.path()).unwrap();
        assert_eq!(Manifest::load(dir.path()).unwrap(), Some(manifest(8)));
        assert_eq!(manifest(12).create_or_check(dir.path()).unwrap(), Some(8), "more robots grow the run");
        assert_eq!(Manifest::load(dir.path()).unwrap(), Some(manifest(12)));
        let e = manifest(9).create_or_check(dir.path()).unwrap_err().to_string();
        assert!(e.contains("robots: requested 9, directory has 12 (a dataset can grow, not shrink)"), "{e}");
        let mut bigger_other = manifest(16);
        bigger_other.seed = 2;
        let e = bigger_other.create_or_check(dir.path()).unwrap_err().to_string();
        assert!(e.contains("seed: requested 2"), "{e}");
        let mut other = manifest(12);
        other.sim.dt = 2e-3;
        let e = other.create_or_check(dir.path()).unwrap_err().to_string();
        assert!(e.contains("sim.dt: requested 0.002, directory has 0.001"), "{e}");
        std::fs::write(dir.path().join(FILE), "seed = 'x'").unwrap();
        let e = manifest(12).create_or_check(dir.path()).unwrap_err().to_string();
        assert!(e.contains("manifest.toml: not a dynforge run manifest"), "{e}");
    }
}
