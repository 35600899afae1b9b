//! The caches' file layout: an 8-byte magic, little-endian numbers, and the content hash of everything before it, so
//! a damaged or truncated cache is detected and rebuilt instead of read. Both ends stream through a buffer of
//! [`CHUNK`] bytes: a cache of the paper's 8,192 robots (16 GB of windows) is never held twice in memory, once as
//! values and once as bytes.

use std::io::{self, Read, Write};

use dynforge_proto::{ContentHasher, NUM_LABELS};

/// Bytes converted, hashed and written (or read) at a time.
const CHUNK: usize = 1 << 16;

/// Writes an encoding to `W`. A write error is kept and returned by [`Encoder::finish`]; nothing is written after it.
pub(crate) struct Encoder<W: Write> {
    out: W,
    hash: ContentHasher,
    buffer: Vec<u8>,
    error: Option<io::Error>,
}

impl<W: Write> Encoder<W> {
    pub(crate) fn new(out: W, magic: &[u8; 8]) -> Self {
        let mut e = Encoder { out, hash: ContentHasher::default(), buffer: Vec::with_capacity(CHUNK), error: None };
        e.raw(magic);
        e
    }

    /// Bytes as they are (an encoding's own bytes, copied).
    pub(crate) fn raw(&mut self, bytes: &[u8]) -> &mut Self {
        for piece in bytes.chunks(CHUNK) {
            self.buffer.extend_from_slice(piece);
            self.spill(false);
        }
        self
    }

    fn values<const N: usize, T>(&mut self, v: impl IntoIterator<Item = T>, to: fn(T) -> [u8; N]) -> &mut Self {
        for x in v {
            self.buffer.extend_from_slice(&to(x));
            self.spill(false);
        }
        self
    }

    pub(crate) fn u64s(&mut self, v: impl IntoIterator<Item = u64>) -> &mut Self {
        self.values(v, u64::to_le_bytes)
    }

    pub(crate) fn f32s(&mut self, v: &[f32]) -> &mut Self {
        self.values(v.iter().copied(), f32::to_le_bytes)
    }

    pub(crate) fn f64s(&mut self, v: &[f64]) -> &mut Self {
        self.values(v.iter().copied(), f64::to_le_bytes)
    }

    /// A length-prefixed byte string.
    pub(crate) fn bytes(&mut self, v: &[u8]) -> &mut Self {
        self.u64s([v.len() as u64]).raw(v)
    }

    /// Hashes and writes the buffer once it holds a chunk (or at all, when `all`).
    fn spill(&mut self, all: bool) {
        if self.buffer.len() < CHUNK && !all {
            return;
        }
        self.hash.update(&self.buffer);
        if self.error.is_none() {
            self.error = self.out.write_all(&self.buffer).err();
        }
        self.buffer.clear();
    }

    /// The checksum written after everything else; the writer back, or the first write error.
    pub(crate) fn finish(mut self) -> io::Result<W> {
        self.spill(true);
        let check = self.hash.finish().to_le_bytes();
        match self.error.take() {
            Some(e) => Err(e),
            None => self.out.write_all(&check).and_then(|()| self.out.flush()).map(|()| self.out),
        }
    }
}

impl Encoder<Vec<u8>> {
    /// An encoding held in memory (a small one: a list of shards).
    pub(crate) fn into_bytes(self) -> Vec<u8> {
        self.finish().expect("writing to memory does not fail")
    }
}

/// Reads an encoding of known length from `R`, checking its checksum at the end ([`Decoder::finish`]). A count that
/// claims more values than the bytes left is refused before anything is allocated for it, so a damaged file never
/// asks for more memory than its own size.
pub(crate) struct Decoder<R: Read> {
    input: R,
    /// Bytes before the checksum not yet read.
    left: u64,
    hash: ContentHasher,
}

impl<R: Read> Decoder<R> {
    /// `None` unless the `len` bytes `input` holds (checksum included) start with `magic`.
    pub(crate) fn open(input: R, len: u64, magic: &[u8; 8]) -> Option<Self> {
        let mut d = Decoder { input, left: len.checked_sub(8)?, hash: ContentHasher::default() };
        let mut head = [0; 8];
        d.fill(&mut head)?;
        (head == *magic).then_some(d)
    }

    fn fill(&mut self, buffer: &mut [u8]) -> Option<()> {
        self.left = self.left.checked_sub(buffer.len() as u64)?;
        self.input.read_exact(buffer).ok()?;
        self.hash.update(buffer);
        Some(())
    }

    /// `total` bytes, a chunk at a time, each passed to `each`; `None` if fewer are left.
    fn chunks(&mut self, total: usize, mut each: impl FnMut(&[u8])) -> Option<()> {
        (total as u64 <= self.left).then_some(())?;
        let mut buffer = vec![0; CHUNK.min(total)];
        let mut rest = total;
        while rest > 0 {
            let k = rest.min(CHUNK);
            self.fill(&mut buffer[..k])?;
            each(&buffer[..k]);
            rest -= k;
        }
        Some(())
    }

    /// `n` values of `N` bytes each, decoded by `from` (a `from_le_bytes`).
    fn values<const N: usize, T>(&mut self, n: usize, from: fn([u8; N]) -> T) -> Option<Vec<T>> {
        let total = n.checked_mul(N)?;
        (total as u64 <= self.left).then_some(())?;
        let mut out = Vec::with_capacity(n);
        // CHUNK is a multiple of N: no value straddles two chunks.
        self.chunks(total, |b| out.extend(b.chunks_exact(N).map(|c| from(c.try_into().expect("chunks of N bytes")))))?;
        Some(out)
    }

    pub(crate) fn u64(&mut self) -> Option<u64> {
        let mut b = [0; 8];
        self.fill(&mut b)?;
        Some(u64::from_le_bytes(b))
    }

    /// A count or size, which must fit this machine.
    pub(crate) fn usize(&mut self) -> Option<usize> {
        self.u64()?.try_into().ok()
    }

    /// A byte string written by [`Encoder::bytes`].
    pub(crate) fn bytes(&mut self) -> Option<Vec<u8>> {
        let n = self.usize()?;
        self.values(n, |[b]: [u8; 1]| b)
    }

    /// The next `total` bytes, unread but hashed, each chunk passed to `each` (copied to another encoding).
    pub(crate) fn pass(&mut self, total: usize, each: impl FnMut(&[u8])) -> Option<()> {
        self.chunks(total, each)
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

    /// `Some` when everything was read and the checksum that follows matches.
    pub(crate) fn finish(mut self) -> Option<R> {
        (self.left == 0).then_some(())?;
        let mut check = [0; 8];
        self.input.read_exact(&mut check).ok()?;
        (u64::from_le_bytes(check) == self.hash.finish()).then_some(self.input)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decoder<'a>(bytes: &'a [u8], magic: &[u8; 8]) -> Option<Decoder<&'a [u8]>> {
        Decoder::open(bytes, bytes.len() as u64, magic)
    }

    #[test]
    fn values_come_back_and_any_damage_is_refused() {
        let mut e = Encoder::new(Vec::new(), b"TESTFMT1");
        e.u64s([3, u64::MAX]).f32s(&[1.5, -2.0]).f64s(&[std::f64::consts::PI]).bytes(b"name");
        let bytes = e.into_bytes();
        let mut d = decoder(&bytes, b"TESTFMT1").unwrap();
        assert_eq!(d.u64s(2).unwrap(), [3, u64::MAX]);
        assert_eq!(d.f32s(2).unwrap(), [1.5, -2.0]);
        assert_eq!(d.f64s(1).unwrap(), [std::f64::consts::PI]);
        assert_eq!(d.bytes().unwrap(), b"name");
        assert!(d.finish().is_some());
        assert!(decoder(&bytes, b"OTHERFMT").is_none());
        let read_all = |b: &[u8]| {
            let mut d = decoder(b, b"TESTFMT1")?;
            let read = (d.u64s(2)?, d.f32s(2)?, d.f64s(1)?, d.bytes()?);
            d.finish().map(|_| read)
        };
        for i in [0, 9, bytes.len() - 1] {
            let mut bad = bytes.clone();
            bad[i] ^= 1;
            assert!(read_all(&bad).is_none(), "byte {i}");
        }
        assert!(read_all(&bytes[..bytes.len() - 1]).is_none(), "truncated");
        let mut short = decoder(&bytes, b"TESTFMT1").unwrap();
        short.u64s(2).unwrap();
        assert!(short.finish().is_none(), "values left unread");
    }

    /// What a stream of several chunks gives, and what a count larger than the file is refused as.
    #[test]
    fn long_encodings_stream_and_impossible_counts_allocate_nothing() {
        let values: Vec<f32> = (0..CHUNK + 7).map(|i| i as f32 * 0.5).collect();
        let mut e = Encoder::new(Vec::new(), b"TESTFMT2");
        e.u64s([values.len() as u64]).f32s(&values);
        let bytes = e.into_bytes();
        let mut whole = Vec::new();
        whole.extend(b"TESTFMT2");
        whole.extend((values.len() as u64).to_le_bytes());
        values.iter().for_each(|v| whole.extend(v.to_le_bytes()));
        whole.extend(dynforge_proto::content_hash(&whole).to_le_bytes());
        assert_eq!(bytes, whole, "the layout: magic, values, checksum of all before it");
        let mut d = decoder(&bytes, b"TESTFMT2").unwrap();
        let n = d.usize().unwrap();
        assert_eq!(d.f32s(n).unwrap(), values);
        assert!(d.finish().is_some());

        let mut d = decoder(&bytes, b"TESTFMT2").unwrap();
        d.usize().unwrap();
        assert!(d.f32s(usize::MAX / 8).is_none() && d.f64s(values.len()).is_none(), "more than the bytes left");
    }
}
