//! Double-buffered checkpoint storage over any NOR flash (`embedded_storage::nor_flash`).
//!
//! Two slots, each a whole number of erase sectors. A checkpoint goes to the slot that does not
//! hold the newest one: erase, write the payload, then write the header last. The header carries
//! a magic, the record format version, a generation counter, the payload length and CRC, and its
//! own CRC. A reset at any moment of a write leaves that slot without a valid header (erased, or
//! header CRC/payload CRC failing), so the other slot — the previous checkpoint — is still loaded:
//! never only a broken copy.
//!
//! The payload is opaque here (the application puts its resume block and the estimator core's
//! checkpoint image in it, see [`crate::app`]).

use embedded_storage::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};
use estimator_core::checkpoint::crc32;

/// Magic at the start of a slot header.
pub const MAGIC: u32 = u32::from_le_bytes(*b"DIDS");
/// Record format version written by this code (the slot layout, not the payload).
pub const FORMAT: u16 = 1;
/// Header size, bytes (before padding to the flash's write size).
const HEADER: usize = 24;
/// Largest payload this store handles, bytes (a 15-state filter image is 1 068 bytes).
pub const MAX_PAYLOAD: usize = 2048;
/// Largest flash write granularity supported (the STM32H7 writes 32-byte flash words).
const MAX_WRITE: usize = 32;

/// Why a checkpoint could not be stored or loaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StoreError {
    /// The flash driver failed.
    Flash(NorFlashErrorKind),
    /// The payload does not fit a slot or [`MAX_PAYLOAD`].
    TooLarge,
    /// The flash is too small for two slots, or its geometry is not supported.
    Geometry,
    /// A slot holds a record of another format version (refused, not loaded).
    Format {
        /// Version found.
        found: u16,
    },
}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            StoreError::Flash(k) => write!(f, "flash error {k:?}"),
            StoreError::TooLarge => write!(f, "checkpoint larger than a slot"),
            StoreError::Geometry => write!(f, "flash too small for two checkpoint slots"),
            StoreError::Format { found } => write!(
                f,
                "checkpoint record format {found}, this firmware reads {FORMAT}"
            ),
        }
    }
}

fn flash<E: NorFlashError>(e: E) -> StoreError {
    StoreError::Flash(e.kind())
}

/// A valid record found in a slot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Found {
    /// Slot index (0 or 1).
    pub slot: usize,
    /// Generation (higher is newer).
    pub generation: u32,
    /// Payload length, bytes.
    pub len: usize,
}

/// Two checkpoint slots over a NOR flash region (the whole of `F`'s capacity).
pub struct CheckpointStore<F> {
    flash: F,
    slot_size: u32,
    newest: Option<Found>,
}

impl<F: NorFlash> CheckpointStore<F> {
    /// A store over `flash`: two slots of half its capacity each (rounded down to erase sectors).
    pub fn new(flash: F) -> Result<Self, StoreError> {
        let erase = F::ERASE_SIZE as u32;
        if F::WRITE_SIZE > MAX_WRITE || MAX_WRITE % F::WRITE_SIZE != 0 || erase == 0 {
            return Err(StoreError::Geometry);
        }
        let slot_size = (flash.capacity() as u32 / 2) / erase * erase;
        if (slot_size as usize) < pad(HEADER, F::WRITE_SIZE) + F::WRITE_SIZE {
            return Err(StoreError::Geometry);
        }
        Ok(CheckpointStore {
            flash,
            slot_size,
            newest: None,
        })
    }

    /// The flash (tests: inspect or damage it).
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    fn header_len() -> usize {
        pad(HEADER, F::WRITE_SIZE)
    }

    /// Reads and checks the record of `slot`: `Ok(None)` when empty or damaged (ignored),
    /// `Err(Format)` when it holds a record of another format version.
    fn probe(&mut self, slot: usize, buf: &mut [u8]) -> Result<Option<Found>, StoreError> {
        let base = slot as u32 * self.slot_size;
        let mut h = [0u8; HEADER];
        self.flash.read(base, &mut h).map_err(flash)?;
        let word = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        if word(0) != MAGIC || word(20) != crc32(&h[..20]) {
            return Ok(None);
        }
        let format = u16::from_le_bytes([h[4], h[5]]);
        if format != FORMAT {
            return Err(StoreError::Format { found: format });
        }
        let generation = word(8);
        let len = word(12) as usize;
        if len > buf.len()
            || len > MAX_PAYLOAD
            || (Self::header_len() + len) as u32 > self.slot_size
        {
            return Ok(None);
        }
        self.flash
            .read(base + Self::header_len() as u32, &mut buf[..len])
            .map_err(flash)?;
        if crc32(&buf[..len]) != word(16) {
            return Ok(None);
        }
        Ok(Some(Found {
            slot,
            generation,
            len,
        }))
    }

    /// Loads the newest valid checkpoint into `buf`; `Ok(None)` when there is none. A slot of
    /// another record format is refused with [`StoreError::Format`] (only if no slot is valid:
    /// a valid newer record wins).
    pub fn load(&mut self, buf: &mut [u8]) -> Result<Option<Found>, StoreError> {
        let mut best: Option<Found> = None;
        let mut refused = None;
        for slot in 0..2 {
            match self.probe(slot, buf) {
                Ok(Some(f)) => {
                    if best.is_none_or(|b| f.generation > b.generation) {
                        best = Some(f);
                    }
                }
                Ok(None) => {}
                Err(e @ StoreError::Format { .. }) => refused = Some(e),
                Err(e) => return Err(e),
            }
        }
        self.newest = best;
        match (best, refused) {
            (Some(f), _) => {
                // `buf` holds whichever slot was read last: read the winner again.
                self.probe(f.slot, buf)?;
                Ok(Some(f))
            }
            (None, Some(e)) => Err(e),
            (None, None) => Ok(None),
        }
    }

    /// Writes `payload` as the next generation into the slot not holding the newest record.
    /// Returns the generation written. Call [`CheckpointStore::load`] once first (at boot), so
    /// the store knows which slot is the newest.
    pub fn save(&mut self, payload: &[u8]) -> Result<u32, StoreError> {
        let hl = Self::header_len();
        if payload.len() > MAX_PAYLOAD || (hl + payload.len()) as u32 > self.slot_size {
            return Err(StoreError::TooLarge);
        }
        let (slot, generation) = match self.newest {
            Some(f) => (1 - f.slot, f.generation.wrapping_add(1)),
            None => (0, 1),
        };
        let base = slot as u32 * self.slot_size;
        self.flash
            .erase(base, base + self.slot_size)
            .map_err(flash)?;
        // Payload first, in write-size chunks (the last one padded with 0xFF).
        let ws = F::WRITE_SIZE;
        let mut chunk = [0xFFu8; MAX_WRITE];
        let mut off = 0;
        while off < payload.len() {
            let n = (payload.len() - off).min(MAX_WRITE);
            let w = pad(n, ws);
            chunk[..w].fill(0xFF);
            chunk[..n].copy_from_slice(&payload[off..off + n]);
            self.flash
                .write(base + (hl + off) as u32, &chunk[..w])
                .map_err(flash)?;
            off += n;
        }
        // The header last: it commits the record.
        let mut h = [0xFFu8; MAX_WRITE];
        h[0..4].copy_from_slice(&MAGIC.to_le_bytes());
        h[4..6].copy_from_slice(&FORMAT.to_le_bytes());
        h[6..8].copy_from_slice(&[0, 0]);
        h[8..12].copy_from_slice(&generation.to_le_bytes());
        h[12..16].copy_from_slice(&(payload.len() as u32).to_le_bytes());
        h[16..20].copy_from_slice(&crc32(payload).to_le_bytes());
        let c = crc32(&h[..20]);
        h[20..24].copy_from_slice(&c.to_le_bytes());
        self.flash.write(base, &h[..hl]).map_err(flash)?;
        self.newest = Some(Found {
            slot,
            generation,
            len: payload.len(),
        });
        Ok(generation)
    }
}

const fn pad(n: usize, to: usize) -> usize {
    n.div_ceil(to) * to
}

/// NOR flash in RAM: `N` bytes, erase sectors of `SECTOR` bytes, 8-byte writes; enforces NOR
/// semantics (a write may only clear bits of erased bytes). For host tests, and for QEMU over a
/// RAM region that survives a reset (see the QEMU board).
pub struct RamFlash<'a, const SECTOR: usize> {
    mem: &'a mut [u8],
    /// Stop after this many more byte writes (tests: a reset in the middle of a write).
    pub fail_after_bytes: Option<usize>,
}

impl<'a, const SECTOR: usize> RamFlash<'a, SECTOR> {
    /// Flash over `mem` (left as it is: it may hold checkpoints from before a reset).
    pub fn new(mem: &'a mut [u8]) -> Self {
        RamFlash {
            mem,
            fail_after_bytes: None,
        }
    }

    /// The bytes (tests).
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        self.mem
    }
}

/// Errors of [`RamFlash`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RamFlashError {
    /// Outside the region or misaligned.
    OutOfBounds,
    /// Writing to a byte that was not erased.
    NotErased,
    /// The simulated power loss (`fail_after_bytes`) happened.
    PowerLoss,
}

impl NorFlashError for RamFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            RamFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

impl<const SECTOR: usize> embedded_storage::nor_flash::ErrorType for RamFlash<'_, SECTOR> {
    type Error = RamFlashError;
}

impl<const SECTOR: usize> ReadNorFlash for RamFlash<'_, SECTOR> {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let o = offset as usize;
        let src = self
            .mem
            .get(o..o + bytes.len())
            .ok_or(RamFlashError::OutOfBounds)?;
        bytes.copy_from_slice(src);
        Ok(())
    }
    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl<const SECTOR: usize> NorFlash for RamFlash<'_, SECTOR> {
    const WRITE_SIZE: usize = 8;
    const ERASE_SIZE: usize = SECTOR;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let (a, b) = (from as usize, to as usize);
        if a % SECTOR != 0 || b % SECTOR != 0 || b > self.mem.len() || a > b {
            return Err(RamFlashError::OutOfBounds);
        }
        self.mem[a..b].fill(0xFF);
        Ok(())
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let o = offset as usize;
        if o % 8 != 0 || bytes.len() % 8 != 0 || o + bytes.len() > self.mem.len() {
            return Err(RamFlashError::OutOfBounds);
        }
        for (i, &b) in bytes.iter().enumerate() {
            if let Some(n) = self.fail_after_bytes.as_mut() {
                if *n == 0 {
                    return Err(RamFlashError::PowerLoss);
                }
                *n -= 1;
            }
            let cell = &mut self.mem[o + i];
            if *cell != 0xFF {
                return Err(RamFlashError::NotErased);
            }
            *cell = b;
        }
        Ok(())
    }
}

/// No non-volatile storage: checkpoints are not written (boards without flash for them).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoStorage;

impl embedded_storage::nor_flash::ErrorType for NoStorage {
    type Error = NorFlashErrorKind;
}

impl ReadNorFlash for NoStorage {
    const READ_SIZE: usize = 1;
    fn read(&mut self, _offset: u32, _bytes: &mut [u8]) -> Result<(), Self::Error> {
        Err(NorFlashErrorKind::OutOfBounds)
    }
    fn capacity(&self) -> usize {
        0
    }
}

impl NorFlash for NoStorage {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = 1;
    fn erase(&mut self, _from: u32, _to: u32) -> Result<(), Self::Error> {
        Err(NorFlashErrorKind::OutOfBounds)
    }
    fn write(&mut self, _offset: u32, _bytes: &[u8]) -> Result<(), Self::Error> {
        Err(NorFlashErrorKind::OutOfBounds)
    }
}
