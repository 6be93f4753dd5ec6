//! Filter checkpoints: the complete filter state in a versioned, CRC-checked byte image, so a
//! 60-hour run survives a reset. The firmware appends it to a record log in non-volatile storage
//! (`firmware/app/src/checkpoints.rs`: the newest intact record wins), the host can write it to a
//! file.
//!
//! Layout (little-endian): magic `DIDC`, format version u16, state size n u16, model
//! fingerprint u32, update count u32, time f64, temperature reference f64, temperature deviation
//! f64, rejected count u32, x\[n\] f64, P upper triangle row by row f64, CRC-32 (IEEE) u32 of all
//! the bytes before it. A checkpoint from another model configuration (effects, site, noise,
//! propagation) or another format version is refused, never loaded.

use crate::filter::Ekf;
use crate::model::{Model, Propagation};

/// Magic bytes at the start of every checkpoint.
pub const MAGIC: [u8; 4] = *b"DIDC";
/// Format version written by this code.
pub const VERSION: u16 = 1;
const HEADER: usize = 4 + 2 + 2 + 4 + 4 + 8 + 8 + 8 + 4;

/// Bytes a checkpoint of an n-state filter takes.
pub const fn size(n: usize) -> usize {
    HEADER + 8 * n + 8 * n * (n + 1) / 2 + 4
}

/// Why a checkpoint was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(missing_docs)] // fields: what was found and what this filter expects
pub enum CheckpointError {
    /// The output buffer is too small (`needed` bytes).
    BufferTooSmall { needed: usize },
    /// Fewer bytes than a checkpoint of this model needs, or not a checkpoint at all.
    Truncated,
    /// Not a checkpoint (magic bytes differ).
    BadMagic,
    /// Written by another format version.
    Version { found: u16, expected: u16 },
    /// Written for another model configuration.
    ModelMismatch { found: u32, expected: u32 },
    /// The bytes are damaged (CRC mismatch).
    Crc,
    /// The stored state is not usable (non-finite values).
    Invalid,
}

impl core::fmt::Display for CheckpointError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            CheckpointError::BufferTooSmall { needed } => write!(f, "checkpoint needs {needed} bytes"),
            CheckpointError::Truncated => write!(f, "checkpoint truncated"),
            CheckpointError::BadMagic => write!(f, "not a checkpoint"),
            CheckpointError::Version { found, expected } => {
                write!(f, "checkpoint format version {found}, this filter reads {expected}")
            }
            CheckpointError::ModelMismatch { found, expected } => write!(
                f,
                "checkpoint of another model configuration (fingerprint {found:08x}, this model {expected:08x})"
            ),
            CheckpointError::Crc => write!(f, "checkpoint damaged (CRC mismatch)"),
            CheckpointError::Invalid => write!(f, "checkpoint holds non-finite values"),
        }
    }
}

/// The CRC-32 of checkpoints (IEEE 802.3 / ISO-HDLC, reflected, as zlib and the wire protocol),
/// from the `crc` crate: the one CRC implementation of the workspace.
pub const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// CRC-32 of `bytes` ([`CRC32`]).
#[inline]
pub fn crc32(bytes: &[u8]) -> u32 {
    CRC32.checksum(bytes)
}

#[inline]
fn fnv(h: &mut u32, bytes: &[u8]) {
    for &b in bytes {
        *h ^= u32::from(b);
        *h = h.wrapping_mul(0x0100_0193);
    }
}

/// A fingerprint of everything that defines the model: effect names and sizes, site, noise and
/// propagation. Two models with the same fingerprint lay out and propagate their state alike.
#[inline]
pub fn fingerprint(model: &Model<'_>) -> u32 {
    let mut h = 0x811C_9DC5u32;
    for e in model.effects() {
        fnv(&mut h, e.name().as_bytes());
        fnv(&mut h, &(e.params().len() as u32).to_le_bytes());
    }
    let site = model.site();
    fnv(&mut h, &site.latitude_rad.to_le_bytes());
    fnv(&mut h, &site.gravity_mps2.to_le_bytes());
    if site.chart != crate::frames::Chart::Enu {
        // (ENU adds nothing: fingerprints of checkpoints written before charts stay valid.)
        fnv(&mut h, b"chart-polar");
    }
    fnv(&mut h, &model.arw_rad2ps().to_le_bytes());
    match model.propagation() {
        Propagation::Euler => fnv(&mut h, b"euler"),
        Propagation::Rk4 { max_step_s } => {
            fnv(&mut h, b"rk4");
            fnv(&mut h, &max_step_s.to_le_bytes());
        }
    }
    h
}

struct Writer<'a> {
    buf: &'a mut [u8],
    at: usize,
}
impl Writer<'_> {
    #[inline]
    fn put(&mut self, b: &[u8]) {
        self.buf[self.at..self.at + b.len()].copy_from_slice(b);
        self.at += b.len();
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}
impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        out.copy_from_slice(&self.buf[self.at..self.at + N]);
        self.at += N;
        out
    }
    #[inline]
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
    #[inline]
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
}

impl<const CAP: usize> Ekf<'_, CAP> {
    /// Writes the checkpoint image into `buf`; returns its length ([`size`]`(n)`).
    pub fn checkpoint(&self, buf: &mut [u8]) -> Result<usize, CheckpointError> {
        let n = self.model().dim();
        let needed = size(n);
        if buf.len() < needed {
            return Err(CheckpointError::BufferTooSmall { needed });
        }
        let (t_s, steps, temp_ref, temp_dev, rejected) = self.bookkeeping();
        let mut w = Writer { buf, at: 0 };
        w.put(&MAGIC);
        w.put(&VERSION.to_le_bytes());
        w.put(&(n as u16).to_le_bytes());
        w.put(&fingerprint(self.model()).to_le_bytes());
        w.put(&steps.to_le_bytes());
        w.put(&t_s.to_le_bytes());
        w.put(&temp_ref.to_le_bytes());
        w.put(&temp_dev.to_le_bytes());
        w.put(&rejected.to_le_bytes());
        for v in self.state() {
            w.put(&v.to_le_bytes());
        }
        for i in 0..n {
            for j in i..n {
                w.put(&self.cov(i, j).to_le_bytes());
            }
        }
        let crc = crc32(&w.buf[..w.at]);
        w.put(&crc.to_le_bytes());
        Ok(w.at)
    }

    /// Restores the filter from a checkpoint image written by [`Ekf::checkpoint`] for the same
    /// model configuration. On error the filter is unchanged.
    pub fn resume(&mut self, image: &[u8]) -> Result<(), CheckpointError> {
        let n = self.model().dim();
        if image.len() < HEADER {
            return Err(CheckpointError::Truncated);
        }
        let mut r = Reader { buf: image, at: 0 };
        if r.take::<4>() != MAGIC {
            return Err(CheckpointError::BadMagic);
        }
        let version = u16::from_le_bytes(r.take());
        if version != VERSION {
            return Err(CheckpointError::Version {
                found: version,
                expected: VERSION,
            });
        }
        let stored_n = u16::from_le_bytes(r.take()) as usize;
        let found = r.u32();
        let expected = fingerprint(self.model());
        if found != expected || stored_n != n {
            return Err(CheckpointError::ModelMismatch { found, expected });
        }
        let len = size(n);
        if image.len() < len {
            return Err(CheckpointError::Truncated);
        }
        let crc = u32::from_le_bytes([
            image[len - 4],
            image[len - 3],
            image[len - 2],
            image[len - 1],
        ]);
        if crc32(&image[..len - 4]) != crc {
            return Err(CheckpointError::Crc);
        }
        let steps = r.u32();
        let t_s = r.f64();
        let temp_ref = r.f64();
        let temp_dev = r.f64();
        let rejected = r.u32();
        let mut x = [0.0; CAP];
        for v in x.iter_mut().take(n) {
            *v = r.f64();
        }
        let mut p = [[0.0; CAP]; CAP];
        // Index loops: the upper triangle is mirrored into the lower one.
        #[allow(clippy::needless_range_loop)]
        for i in 0..n {
            for j in i..n {
                let v = r.f64();
                p[i][j] = v;
                p[j][i] = v;
            }
        }
        let finite = x[..n].iter().all(|v| v.is_finite())
            && p[..n]
                .iter()
                .all(|row| row[..n].iter().all(|v| v.is_finite()));
        if !(finite && t_s.is_finite()) {
            return Err(CheckpointError::Invalid);
        }
        self.set_all(&x[..n], &p, t_s, steps, temp_ref, temp_dev, rejected);
        Ok(())
    }
}
