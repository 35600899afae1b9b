//! Subnormal floats (below 1.2e-38 in f32) take a slow path in x86 CPUs, tens to hundreds of cycles an operation,
//! and the transformer's training makes them: with the data unchanged, an epoch at 1,024 robots went from 222 to 356
//! CPU s over 9 epochs, and a fresh process resuming at the tenth still took 324. The same epoch with them flushed
//! to zero took 171, less than the first epoch had taken without. The transformer's training steps
//! therefore run with the CPU's flush-to-zero and denormals-are-zero modes; threads that share a step take the mode
//! of the thread that starts it, so the result stays the same on any machine. Elsewhere (evaluation, the physics
//! estimator, identification in f64) the default mode stays.

/// A thread's floating-point mode (x86-64: the control bits of its MXCSR register, not its sticky exception flags;
/// elsewhere nothing is changed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct FloatMode(u32);

impl FloatMode {
    /// Flush-to-zero (results) and denormals-are-zero (inputs).
    #[cfg(target_arch = "x86_64")]
    const FLUSH: u32 = 0x8040;
    /// The exception flags, which operations set and which say nothing of the mode.
    #[cfg(target_arch = "x86_64")]
    const FLAGS: u32 = 0x3f;

    pub(crate) fn current() -> FloatMode {
        #[cfg(target_arch = "x86_64")]
        {
            let mut csr = 0u32;
            // SAFETY: stores this thread's MXCSR into a local.
            unsafe { std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack, preserves_flags)) };
            FloatMode(csr & !Self::FLAGS)
        }
        #[cfg(not(target_arch = "x86_64"))]
        FloatMode(0)
    }

    /// Makes this the calling thread's mode.
    pub(crate) fn apply(self) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: loads control bits read from MXCSR (at most the two mode bits added): no exception is unmasked.
        unsafe {
            std::arch::asm!("ldmxcsr [{}]", in(reg) &self.0, options(nostack, preserves_flags, readonly))
        };
    }

    #[cfg(test)]
    fn flushes(self) -> bool {
        #[cfg(target_arch = "x86_64")]
        return self.0 & Self::FLUSH == Self::FLUSH;
        #[cfg(not(target_arch = "x86_64"))]
        false
    }
}

/// Subnormals flushed to zero on this thread until dropped, when its mode before comes back.
pub(crate) struct FlushToZero {
    before: FloatMode,
}

impl FlushToZero {
    pub(crate) fn on() -> FlushToZero {
        let before = FloatMode::current();
        #[cfg(target_arch = "x86_64")]
        FloatMode(before.0 | FloatMode::FLUSH).apply();
        FlushToZero { before }
    }
}

impl Drop for FlushToZero {
    fn drop(&mut self) {
        self.before.apply();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subnormals_are_flushed_while_the_guard_lives_and_the_mode_comes_back() {
        let tiny = std::hint::black_box(f32::MIN_POSITIVE);
        let half = move || std::hint::black_box(tiny) / std::hint::black_box(2.0f32);
        let before = FloatMode::current();
        assert!(half() > 0.0 && half().is_subnormal(), "the default mode keeps subnormals");
        {
            let _flush = FlushToZero::on();
            if cfg!(target_arch = "x86_64") {
                assert!(FloatMode::current().flushes());
                assert_eq!(half(), 0.0, "flushed to zero");
                let spawned = FloatMode::current();
                let inherited = std::thread::spawn(move || {
                    spawned.apply();
                    half()
                });
                assert_eq!(inherited.join().unwrap(), 0.0, "a thread given the mode flushes too");
            }
        }
        assert_eq!(FloatMode::current(), before);
        assert!(half().is_subnormal(), "the mode before is back");
    }
}
