//! Train/validation split by robot, deterministic from a seed: no validation robot is ever seen in training.

use dynforge_proto::content_hash;

/// Which side of the split a sample belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Split {
    Train,
    Validation,
}

/// Robot `robot` goes to validation with probability `fraction`, decided by a hash of `(seed, robot)` alone: the
/// same on every machine and in every process, whatever order the shards arrive in.
pub fn split_of(seed: u64, robot: u64, fraction: f64) -> Split {
    let mut key = [0u8; 16];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..].copy_from_slice(&robot.to_le_bytes());
    let u = (content_hash(&key) >> 11) as f64 / (1u64 << 53) as f64;
    if u < fraction { Split::Validation } else { Split::Train }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_split_is_by_robot_deterministic_and_near_the_fraction() {
        let val = (0..10_000u64).filter(|&r| split_of(3, r, 0.2) == Split::Validation).count();
        // Binomial(10000, 0.2): sd = 40; 5 sd = 200.
        assert!((val as i64 - 2000).abs() < 200, "{val}");
        for r in 0..100 {
            assert_eq!(split_of(3, r, 0.2), split_of(3, r, 0.2));
        }
        let differs = (0..1000u64).filter(|&r| split_of(3, r, 0.5) != split_of(4, r, 0.5)).count();
        assert!(differs > 300, "another seed draws another split");
        assert_eq!(split_of(3, 7, 0.0), Split::Train);
        assert_eq!(split_of(3, 7, 1.0), Split::Validation);
    }
}
