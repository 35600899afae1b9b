//! The caches' file layout: an 8-byte magic, little-endian numbers, and the content hash of everything before it, so
//! a damaged or truncated cache is detected and rebuilt instead of read.

use dynforge_proto::NUM_LABELS;
use dynforge_proto::content_hash;

pub(crate) struct Encoder(Vec<u8>);

impl Encoder {
    pub(crate) fn new(magic: &[u8; 8], capacity: usize) -> Self {
        let mut out = Vec::with_capacity(capacity + 16);
        out.extend(magic);
        Encoder(out)
    }

    pub(crate) fn u64s(&mut self, v: impl IntoIterator<Item = u64>) -> &mut Self {
        v.into_iter().for_each(|x| self.0.extend(x.to_le_bytes()));
        self
    }

    pub(crate) fn f32s(&mut self, v: &[f32]) -> &mut Self {
        v.iter().for_each(|x| self.0.extend(x.to_le_bytes()));
        self
    }

    pub(crate) fn f64s(&mut self, v: &[f64]) -> &mut Self {
        v.iter().for_each(|x| self.0.extend(x.to_le_bytes()));
        self
    }

    /// A length-prefixed byte string.
    pub(crate) fn bytes(&mut self, v: &[u8]) -> &mut Self {
        self.u64s([v.len() as u64]);
        self.0.extend(v);
        self
    }

    pub(crate) fn finish(mut self) -> Vec<u8> {
        let check = content_hash(&self.0);
        self.0.extend(check.to_le_bytes());
        self.0
    }
}

pub(crate) struct Decoder<'a> {
    body: &'a [u8],
    at: usize,
}

impl<'a> Decoder<'a> {
    /// `None` unless `bytes` carries `magic` and an intact checksum.
    pub(crate) fn open(bytes: &'a [u8], magic: &[u8; 8]) -> Option<Self> {
        let (body, check) = bytes.split_at_checked(bytes.len().checked_sub(8)?)?;
        (content_hash(body).to_le_bytes() == check && body.starts_with(magic)).then_some(Decoder { body, at: 8 })
    }

    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let s = self.body.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(s)
    }

    pub(crate) fn u64(&mut self) -> Option<u64> {
        self.values(1, u64::from_le_bytes)?.pop()
    }

    /// A byte string written by [`Encoder::bytes`].
    pub(crate) fn bytes(&mut self) -> Option<&'a [u8]> {
        let n = self.usize()?;
        self.take(n)
    }

    /// A count or size, which must fit this machine.
    pub(crate) fn usize(&mut self) -> Option<usize> {
        self.u64()?.try_into().ok()
    }

    /// `n` values of `N` bytes each, decoded by `from` (a `from_le_bytes`).
    fn values<const N: usize, T>(&mut self, n: usize, from: fn([u8; N]) -> T) -> Option<Vec<T>> {
        let bytes = self.take(n.checked_mul(N)?)?;
        Some(bytes.chunks_exact(N).map(|c| from(c.try_into().expect("chunks of N bytes"))).collect())
    }

    pub(crate) fn u64s(&mut self, n: usize) -> Option<Vec<u64>> {
        self.values(n, u64::from_le_bytes)
    }

    pub(crate) fn f32s(&mut self, n: usize) -> Option<Vec<f32>> {
        self.values(n, f32::from_le_bytes)
    }

    pub(crate) fn f64s(&mut self, n: usize) -> Option<Vec<f64>> {
        self.values(n, f64::from_le_bytes)
    }

    /// `n` label vectors.
    pub(crate) fn label_rows(&mut self, n: usize) -> Option<Vec<[f64; NUM_LABELS]>> {
        let flat = self.f64s(n.checked_mul(NUM_LABELS)?)?;
        Some(flat.chunks_exact(NUM_LABELS).map(|c| c.try_into().expect("rows of NUM_LABELS")).collect())
    }

    /// Whether everything was read.
    pub(crate) fn done(&self) -> bool {
        self.at == self.body.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_come_back_and_any_damage_is_refused() {
        let mut e = Encoder::new(b"TESTFMT1", 0);
        e.u64s([3, u64::MAX]).f32s(&[1.5, -2.0]).f64s(&[std::f64::consts::PI]);
        let bytes = e.finish();
        let mut d = Decoder::open(&bytes, b"TESTFMT1").unwrap();
        assert_eq!(d.u64s(2).unwrap(), [3, u64::MAX]);
        assert_eq!(d.f32s(2).unwrap(), [1.5, -2.0]);
        assert_eq!(d.f64s(1).unwrap(), [std::f64::consts::PI]);
        assert!(d.done() && d.u64().is_none());
        assert!(Decoder::open(&bytes, b"OTHERFMT").is_none());
        for i in [0, 9, bytes.len() - 1] {
            let mut bad = bytes.clone();
            bad[i] ^= 1;
            assert!(Decoder::open(&bad, b"TESTFMT1").is_none(), "byte {i}");
        }
        assert!(Decoder::open(&bytes[..bytes.len() - 1], b"TESTFMT1").is_none());
    }
}
