//! The contracts every dynforge process agrees on.
//!
//! Anything that crosses a process or file boundary is defined here exactly once, so that the generator, the
//! worker, the shards and the trainer can never disagree about what column 17 means: the label layout the trainer
//! regresses (`labels`), the per-link dynamic parameter layout (`params`), the shard schema (`shard`), the run
//! directory and its temporary-file rule (`run_dir`), its lock (`lock`) and its ledger of finished jobs (`ledger`),
//! the run manifest (`manifest`, with the generator's and the simulation's settings it holds: `generator`, `sim`),
//! and what a job is with the messages about it between the coordinator and its workers (`job`).

pub mod family;
pub mod fourier;
pub mod generator;
pub mod job;
pub mod labels;
pub mod ledger;
pub mod lock;
pub mod manifest;
pub mod parallel;
pub mod params;
pub mod run_dir;
pub mod shard;
pub mod sim;
pub mod spread;

pub use labels::{LABELS, Label, LabelKind, NUM_LABELS};
pub use params::{FRICTION_PARAMS_PER_JOINT, INERTIAL_PARAMS_PER_LINK, InertialParam};

/// A stable 64-bit content hash (FNV-1a): of a shard's bytes, recorded in the ledger by the worker that wrote it and
/// checked by everyone who reads the shard as data; of a ledger line, of a cache file. Cheap enough for workers to
/// compute on every shard, and fixed forever (no dependency can change it).
pub fn content_hash(bytes: &[u8]) -> u64 {
    ContentHasher::default().update(bytes).finish()
}

/// [`content_hash`] of bytes that arrive in pieces (a cache file of several gigabytes, streamed): the hash of the
/// pieces' concatenation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ContentHasher(u64);

impl Default for ContentHasher {
    fn default() -> Self {
        ContentHasher(0xcbf2_9ce4_8422_2325)
    }
}

impl ContentHasher {
    pub fn update(&mut self, bytes: &[u8]) -> &mut Self {
        for &b in bytes {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }

    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// [`content_hash`] as the 16 hexadecimal digits that name what it hashes (a family's files, a cache's key).
pub fn content_hash_hex(bytes: &[u8]) -> String {
    format!("{:016x}", content_hash(bytes))
}

#[cfg(test)]
mod tests {
    #[test]
    fn content_hash_is_fnv1a_64() {
        // Published FNV-1a 64 test vectors.
        assert_eq!(super::content_hash(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(super::content_hash(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(super::content_hash(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn content_hash_in_pieces_is_that_of_the_whole() {
        let mut h = super::ContentHasher::default();
        h.update(b"foo").update(b"").update(b"bar");
        assert_eq!(h.finish(), 0x8594_4171_f739_67e8);
    }
}
