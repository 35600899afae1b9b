//! Windowing: the paper's downsampling with a stride (its "sampling rate", in 1 kHz samples) and the offset-based
//! secondary sampler that reuses the samples the stride skips.
//!
//! For offset `o` the downsampled series is `x[o], x[o + s], x[o + 2s], ...`; it is cut into windows of `L` samples,
//! one starting every `hop` samples: `hop = L` (the paper's, and the default) puts them back to back. The offsets are
//! `0, SSR, 2 SSR, ... < s`, so `ceil(s / SSR)` series are used out of `s` possible ones: utilisation `1 / SSR` when
//! SSR divides `s` (the paper's best, L = 64, s = 64, SSR = 16: 4 offsets, 6.25 %, each window spanning 64 x 64 ms =
//! 4.096 s).
//!
//! Back to back, the windows leave a recording's last partial window unread: 44 % of the motion of the generator's
//! 7.4 s recordings at 4.096 s windows. A shorter hop reads it, in windows that overlap.

/// Window geometry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct WindowSpec {
    /// Samples per window (sequence length).
    pub len: usize,
    /// Stride between consecutive samples of a window, in source samples.
    pub stride: usize,
    /// Secondary sampling rate: spacing of the offsets.
    pub ssr: usize,
    /// Downsampled samples from one window's start to the next of the same offset, a divisor of `len`: `len` puts
    /// them back to back, less overlaps them (and keeps the back-to-back windows among them).
    pub hop: usize,
}

impl Default for WindowSpec {
    fn default() -> Self {
        WindowSpec::new(64, 64, 16)
    }
}

/// A window geometry that is not `LEN:STRIDE:SSR[:HOP]` of positive numbers with `HOP` dividing `LEN`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("'{0}': expected positive numbers LEN:STRIDE:SSR, or LEN:STRIDE:SSR:HOP with HOP dividing LEN")]
pub struct WindowSpecError(String);

/// `LEN:STRIDE:SSR`, or `LEN:STRIDE:SSR:HOP` for overlapping windows, as the command line takes it (`64:64:16`).
impl std::str::FromStr for WindowSpec {
    type Err = WindowSpecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let parts: Vec<usize> =
            s.split(':').map(str::parse).collect::<Result<_, _>>().map_err(|_| WindowSpecError(s.into()))?;
        let spec = match parts[..] {
            [len, stride, ssr] => WindowSpec::new(len, stride, ssr),
            [len, stride, ssr, hop] => WindowSpec::new(len, stride, ssr).with_hop(hop),
            _ => return Err(WindowSpecError(s.into())),
        };
        match spec.is_valid() {
            true => Ok(spec),
            false => Err(WindowSpecError(s.into())),
        }
    }
}

/// `LEN:STRIDE:SSR`, with `:HOP` where the windows overlap: what cache keys are made of, so a back-to-back
/// geometry's caches keep their names.
impl std::fmt::Display for WindowSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}:{}", self.len, self.stride, self.ssr)?;
        match self.overlaps() {
            true => write!(f, ":{}", self.hop),
            false => Ok(()),
        }
    }
}

/// One window: source sample `i` of the window is `offset + (start + i) * stride`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Window {
    pub offset: usize,
    pub start: usize,
}

impl WindowSpec {
    /// Back-to-back windows of `len` samples `stride` apart, at offsets `ssr` apart.
    pub const fn new(len: usize, stride: usize, ssr: usize) -> Self {
        WindowSpec { len, stride, ssr, hop: len }
    }

    /// The same windows, one starting every `hop` downsampled samples.
    pub fn with_hop(self, hop: usize) -> Self {
        WindowSpec { hop, ..self }
    }

    /// Whether every size is positive and the hop divides the length (so the back-to-back windows are among the
    /// overlapping ones).
    pub fn is_valid(&self) -> bool {
        self.len > 0 && self.stride > 0 && self.ssr > 0 && self.hop > 0 && self.len.is_multiple_of(self.hop)
    }

    /// Whether a window shares samples with the next of its offset.
    pub fn overlaps(&self) -> bool {
        self.hop < self.len
    }

    /// Each of a recording's `count` windows' place among its offset's (0 the first), listed as [`Self::windows`]
    /// lists them: offset by offset, whose counts differ by at most one and do not rise with the offset, so the first
    /// `count % offsets` hold one more.
    pub fn places(&self, count: usize) -> Vec<usize> {
        let offsets = self.offsets().count().max(1);
        let (q, r) = (count / offsets, count % offsets);
        (0..offsets).flat_map(|o| 0..q + usize::from(o < r)).collect()
    }

    /// Of a recording's `count` windows, which are back to back (all of them unless they overlap): the windows the
    /// default hop gives, and what `evaluate` scores whatever the hop, so that models trained with different hops
    /// are scored on the same windows. A hop divides `len`, so they are among the overlapping ones.
    pub fn back_to_back(&self, count: usize) -> Vec<bool> {
        self.places(count).into_iter().map(|k| (k * self.hop).is_multiple_of(self.len.max(1))).collect()
    }

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

    /// Every window of a recording of `samples` source samples: offset by offset, each offset's in time order.
    pub fn windows(&self, samples: usize) -> Vec<Window> {
        let hop = self.hop.max(1);
        let mut out = Vec::new();
        for offset in self.offsets() {
            if offset >= samples {
                continue;
            }
            let downsampled = (samples - 1 - offset) / self.stride + 1;
            if let Some(room) = downsampled.checked_sub(self.len) {
                out.extend((0..=room / hop).map(|w| Window { offset, start: w * hop }));
            }
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
        assert_eq!(WindowSpec::new(8, 64, 24).offsets().count(), 3);
        // Spans: 4,096 samples from the window's first index, on 16-sample blocks.
        assert_eq!(spec.block(), 16);
        assert_eq!(spec.samples(&w[1], 10_000), 4096..8192);
        assert_eq!(spec.samples(&w[2], 10_000), 16..4112);
        assert_eq!(spec.samples(&Window { offset: 48, start: 64 }, 10_000), 4144..8240);
        assert_eq!(spec.samples(&Window { offset: 0, start: 0 }, 4000), 0..4000);
        assert_eq!(WindowSpec::new(8, 64, 24).block(), 8);
        for win in &w {
            let span = spec.samples(win, 10_000);
            assert!(spec.indices(win).all(|i| span.contains(&i)));
            assert!(span.start % spec.block() == 0 && span.end % spec.block() == 0);
        }
    }

    #[test]
    fn a_shorter_hop_reads_the_motion_back_to_back_windows_leave() {
        // 7,400 samples (a generated recording's 7.4 s): 115 or 116 downsampled samples per offset, so one
        // back-to-back window of 64 per offset (4,096 of the 7,400 samples from offset 0), two at hop 32, four at 16.
        let spec = WindowSpec::default();
        let samples = 7_400;
        for (hop, per_offset, reach) in [(64, 1, 4096), (32, 2, 6144), (16, 4, 7168)] {
            let s = spec.with_hop(hop);
            let w = s.windows(samples);
            assert_eq!(w.len(), 4 * per_offset, "hop {hop}");
            assert!(w.iter().all(|w| w.start % hop == 0 && s.samples(w, samples).len() == 4096), "hop {hop}");
            let end = w.iter().filter(|w| w.offset == 0).map(|w| s.samples(w, samples).end).max();
            assert_eq!(end, Some(reach), "hop {hop}");
            assert_eq!(s.overlaps(), hop < 64);
            // The back-to-back windows are among them, and are what hop 64 gives.
            let kept: Vec<Window> = w.iter().zip(s.back_to_back(w.len())).filter(|p| p.1).map(|p| *p.0).collect();
            assert_eq!(kept, spec.windows(samples), "hop {hop}");
        }
        // Parsed and printed: a back-to-back geometry prints as it always has (cache names are made of it).
        assert_eq!("64:64:16".parse::<WindowSpec>(), Ok(spec));
        assert_eq!("64:64:16:32".parse::<WindowSpec>(), Ok(spec.with_hop(32)));
        assert_eq!(spec.with_hop(32).to_string(), "64:64:16:32");
        assert_eq!(spec.with_hop(64).to_string(), "64:64:16");
        for bad in ["64:64:16:0", "64:64:16:65", "64:64:16:24", "64:64", "64:64:16:8:1", "0:64:16", "64:x:16"] {
            assert!(bad.parse::<WindowSpec>().is_err(), "{bad}");
        }
    }

    #[test]
    fn windows_of_one_offset_do_not_overlap_and_offsets_interleave() {
        let spec = WindowSpec::new(4, 8, 2);
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
