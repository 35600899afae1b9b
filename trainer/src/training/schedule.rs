//! Learning-rate schedule: linear warmup from 0 to the peak, then cosine decay to a tenth of it.

/// Learning rate per optimisation step.
#[derive(Debug, Clone, Copy)]
pub struct Schedule {
    peak: f64,
    warmup: usize,
    total: usize,
}

/// Final learning rate as a share of the peak.
const FLOOR: f64 = 0.1;

impl Schedule {
    /// `warmup` is the share of the `total` steps spent warming up.
    pub fn new(peak: f64, warmup: f64, total: usize) -> Schedule {
        let total = total.max(1);
        Schedule { peak, warmup: ((warmup.clamp(0.0, 1.0) * total as f64).round() as usize).max(1), total }
    }

    /// Learning rate of step `step` (0-based); steps past the end keep the floor.
    pub fn lr(&self, step: usize) -> f64 {
        if step < self.warmup {
            return self.peak * (step + 1) as f64 / self.warmup as f64;
        }
        let span = (self.total - self.warmup.min(self.total)).max(1) as f64;
        let progress = ((step - self.warmup) as f64 / span).min(1.0);
        self.peak * (FLOOR + (1.0 - FLOOR) * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warms_up_linearly_then_decays_by_a_half_cosine_to_the_floor() {
        let s = Schedule::new(1.0, 0.1, 100);
        assert!((s.lr(0) - 0.1).abs() < 1e-15 && (s.lr(9) - 1.0).abs() < 1e-15);
        assert!((s.lr(10) - 1.0).abs() < 1e-15);
        // Half way through the decay the cosine term is 1/2.
        assert!((s.lr(55) - (FLOOR + (1.0 - FLOOR) * 0.5)).abs() < 1e-12);
        assert!((s.lr(100) - FLOOR).abs() < 1e-15 && (s.lr(1000) - FLOOR).abs() < 1e-15);
        assert!((1..100).all(|k| k <= 10 || s.lr(k) <= s.lr(k - 1)));
    }
}
