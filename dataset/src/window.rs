//! Windowing: the paper's downsampling with a stride (its "sampling rate", in 1 kHz samples) and the offset-based
//! secondary sampler that reuses the samples the stride skips.
//!
//! For offset `o` the downsampled series is `x[o], x[o + s], x[o + 2s], ...`; it is cut into consecutive,
//! non-overlapping windows of `L` samples. The offsets are `0, SSR, 2 SSR, ... < s`, so `ceil(s / SSR)` series are
//! used out of `s` possible ones: utilisation `1 / SSR` when SSR divides `s` (the paper's best, L = 64, s = 64,
//! SSR = 16: 4 offsets, 6.25 %, each window spanning 64 x 64 ms = 4.096 s).

/// Window geometry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WindowSpec {
    /// Samples per window (sequence length).
    pub len: usize,
    /// Stride between consecutive samples of a window, in source samples.
    pub stride: usize,
    /// Secondary sampling rate: spacing of the offsets.
    pub ssr: usize,
}

impl Default for WindowSpec {
    fn default() -> Self {
        WindowSpec { len: 64, stride: 64, ssr: 16 }
    }
}

/// A window geometry that is not `LEN:STRIDE:SSR` of three positive numbers.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("'{0}': expected three positive numbers LEN:STRIDE:SSR")]
pub struct WindowSpecError(String);

/// `LEN:STRIDE:SSR`, as the command line takes it (`64:64:16`).
impl std::str::FromStr for WindowSpec {
    type Err = WindowSpecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let parts: Vec<usize> =
            s.split(':').map(str::parse).collect::<Result<_, _>>().map_err(|_| WindowSpecError(s.into()))?;
        match parts[..] {
            [len, stride, ssr] if len > 0 && stride > 0 && ssr > 0 => Ok(WindowSpec { len, stride, ssr }),
            _ => Err(WindowSpecError(s.into())),
        }
    }
}

impl std::fmt::Display for WindowSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}:{}", self.len, self.stride, self.ssr)
    }
}

/// One window: source sample `i` of the window is `offset + (start + i) * stride`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Window {
    pub offset: usize,
    pub start: usize,
}

impl WindowSpec {
    /// The secondary sampler's offsets.
    pub fn offsets(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.stride).step_by(self.ssr.max(1))
    }

    /// Share of the source samples some window uses (for series long enough to hold windows).
    pub fn utilisation(&self) -> f64 {
        self.offsets().count() as f64 / self.stride as f64
    }

    /// Duration a window spans, for source samples `dt` apart.
    pub fn span(&self, dt: f64) -> f64 {
        (self.len * self.stride) as f64 * dt
    }

    /// Every window of a recording of `samples` source samples.
    pub fn windows(&self, samples: usize) -> Vec<Window> {
        let mut out = Vec::new();
        for offset in self.offsets() {
            if offset >= samples {
                continue;
            }
            let downsampled = (samples - 1 - offset) / self.stride + 1;
            out.extend((0..downsampled / self.len).map(|w| Window { offset, start: w * self.len }));
        }
        out
    }

    /// The source samples a window stands for, each of its steps standing for the `stride` samples from it on:
    /// `first .. first + len * stride`, cut at the recording's end. Physics reads the window's torques over this
    /// span at full rate. Bounds are multiples of [`Self::block`], but for the recording's end.
    pub fn samples(&self, w: &Window, recording: usize) -> std::ops::Range<usize> {
        let first = w.offset + w.start * self.stride;
        first..(first + self.len * self.stride).min(recording)
    }

    /// The largest run of samples every window span starts and ends on (but at a recording's end).
    pub fn block(&self) -> usize {
        let gcd = |mut a: usize, mut b: usize| {
            while b != 0 {
                (a, b) = (b, a % b);
            }
            a
        };
        gcd(self.stride, self.ssr).max(1)
    }

    /// Source sample indices of a window.
    pub fn indices(&self, w: &Window) -> impl Iterator<Item = usize> + '_ {
        let (offset, start, stride) = (w.offset, w.start, self.stride);
        (0..self.len).map(move |i| offset + (start + i) * stride)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_and_offset_counts_match_the_formula() {
        let spec = WindowSpec::default();
        assert_eq!(spec.offsets().collect::<Vec<_>>(), [0, 16, 32, 48]);
        assert_eq!(spec.utilisation(), 1.0 / 16.0);
        assert!((spec.span(1e-3) - 4.096).abs() < 1e-12);
        // 10,000 samples: offset o gives floor((9999 - o) / 64) + 1 = 157 downsampled samples for every o < 64,
        // hence floor(157 / 64) = 2 windows per offset, 8 in all.
        let w = spec.windows(10_000);
        assert_eq!(w.len(), 8);
        for win in &w {
            let idx: Vec<usize> = spec.indices(win).collect();
            assert_eq!(idx.len(), 64);
            assert!(idx.windows(2).all(|p| p[1] - p[0] == 64));
            assert!(*idx.last().unwrap() < 10_000);
        }
        // Exactly one window fits in 64 x 64 - 63 samples at offset 0 and none at the others.
        assert_eq!(spec.windows(64 * 63 + 1), vec![Window { offset: 0, start: 0 }]);
        assert!(spec.windows(64 * 63).is_empty());
        // SSR that does not divide the stride: offsets 0, 24, 48 -> ceil(64 / 24) = 3.
        assert_eq!(WindowSpec { len: 8, stride: 64, ssr: 24 }.offsets().count(), 3);
        // Spans: 4,096 samples from the window's first index, on 16-sample blocks.
        assert_eq!(spec.block(), 16);
        assert_eq!(spec.samples(&w[1], 10_000), 4096..8192);
        assert_eq!(spec.samples(&w[2], 10_000), 16..4112);
        assert_eq!(spec.samples(&Window { offset: 48, start: 64 }, 10_000), 4144..8240);
        assert_eq!(spec.samples(&Window { offset: 0, start: 0 }, 4000), 0..4000);
        assert_eq!(WindowSpec { len: 8, stride: 64, ssr: 24 }.block(), 8);
        for win in &w {
            let span = spec.samples(win, 10_000);
            assert!(spec.indices(win).all(|i| span.contains(&i)));
            assert!(span.start % spec.block() == 0 && span.end % spec.block() == 0);
        }
    }

    #[test]
    fn windows_of_one_offset_do_not_overlap_and_offsets_interleave() {
        let spec = WindowSpec { len: 4, stride: 8, ssr: 2 };
        let w = spec.windows(200);
        let mut seen = std::collections::HashSet::new();
        for win in &w {
            for i in spec.indices(win) {
                assert!(seen.insert(i), "sample {i} used twice");
                assert_eq!((i - win.offset) % 8, 0);
            }
        }
        // 4 offsets; offset o has floor((199 - o) / 8) + 1 = 25 samples -> 6 windows (24 samples) each.
        assert_eq!(w.len(), 24);
        assert_eq!(seen.len(), 96);
    }
}
