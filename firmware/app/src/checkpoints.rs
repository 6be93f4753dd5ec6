//! Checkpoint storage over any NOR flash (`embedded_storage::nor_flash`): an append-only record
//! log across the flash's erase sectors, so a sector is erased once per *sector-full* of
//! checkpoints instead of once per checkpoint.
//!
//! # Layout
//!
//! The region is `capacity / ERASE_SIZE` sectors (at least two). Each sector holds records back
//! to back from its start, every record aligned to the flash's write size `W`:
//!
//! ```text
//! record = header (24 bytes, padded to W) ++ payload (padded to W with 0xFF)
//! header = magic "DIDS" u32 | format u16 | 0 u16 | generation u32 | payload length u32
//!        | payload CRC-32 u32 | header CRC-32 u32 (of the 20 bytes before it)      (little-endian)
//! ```
//!
//! A checkpoint is appended after the newest record of the active sector: payload first, the
//! header last (it commits the record). When the active sector is full, the next sector (the
//! one holding the oldest records) is erased and the log continues at its start. The newest
//! record is the valid one with the highest generation, in whatever sector.
//!
//! # Power loss
//!
//! A reset at any moment leaves the newest *committed* record loadable: an interrupted append
//! leaves an erased or damaged header (its CRC fails), which ends the scan of that sector, and
//! the records before it are untouched; an interrupted erase only touches the sector holding
//! the oldest records. Before appending, the target bytes are checked to be erased; if they are
//! not (the remains of an interrupted append), the log moves on to the next sector rather than
//! program over them. (Tested at every byte of a write and of an erase: `tests/checkpoints.rs`.)
//!
//! # Wear
//!
//! With `R` records per sector, a checkpoint costs `1/R` erases. On the STM32H743 (128-KiB
//! sectors, 32-byte flash words) the application's 15-state checkpoint payload is 1 865 bytes
//! (with the sample screening's state), its record 1 920 bytes, `R` = 68; at the default
//! `checkpoint_every: 10` and a 60-s filter period (144 checkpoints a day) that is 2.12 erases a
//! day shared by two sectors, 1.06 per sector: 10 000 cycles last ≈ 26 years of continuous
//! running (the old two-slot store erased a sector per checkpoint: 72 erases a day per sector,
//! ≈ 5 months).
//! `tests/checkpoints.rs` measures this by counting erases.
//!
//! The payload is opaque here (the application puts its resume block and the estimator core's
//! checkpoint image in it, see [`crate::app`]).

use embedded_storage::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};
use estimator_core::checkpoint::CRC32;

/// Magic at the start of a record header.
pub const MAGIC: u32 = u32::from_le_bytes(*b"DIDS");
/// Record format version written by this code (2: the append-only log; 1 was two slots).
pub const FORMAT: u16 = 2;
/// Header size, bytes (before padding to the flash's write size).
pub const HEADER: usize = 24;
/// Largest payload this store handles, bytes: the application's payload is 1 865 bytes at the
/// default configuration (resume block 20 + configuration 137 + screening state 640 + the
/// 15-state filter image 1 068) and at most 1 881 for any configuration (`tests/checkpoints.rs`).
/// The application keeps its buffer of this size in its state (static), not on the stack.
pub const MAX_PAYLOAD: usize = 1920;
/// Largest flash write granularity supported (the STM32H7 writes 32-byte flash words).
const MAX_WRITE: usize = 32;

/// Why a checkpoint could not be stored or loaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StoreError {
    /// The flash driver failed.
    Flash(NorFlashErrorKind),
    /// The payload does not fit a sector or [`MAX_PAYLOAD`].
    TooLarge,
    /// The flash is too small for two sectors, or its geometry is not supported.
    Geometry,
    /// The log holds records of another format version only (refused, not loaded).
    Format {
        /// Version found.
        found: u16,
    },
}

impl StoreError {
    /// Appends the error's text to a fault detail (without `core::fmt`: the firmware's flash;
    /// `Display` writes the same).
    pub fn describe(&self, m: &mut protocol::Detail) {
        match *self {
            StoreError::Flash(k) => m.text("flash error ").text(match k {
                NorFlashErrorKind::NotAligned => "NotAligned",
                NorFlashErrorKind::OutOfBounds => "OutOfBounds",
                _ => "Other",
            }),
            StoreError::TooLarge => m.text("checkpoint larger than a sector"),
            StoreError::Geometry => m.text("flash too small for two checkpoint sectors"),
            StoreError::Format { found } => m
                .text("checkpoint record format ")
                .dec(found.into())
                .text(", this firmware reads ")
                .dec(FORMAT.into()),
        };
    }
}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let mut m = protocol::Detail::new();
        self.describe(&mut m);
        f.write_str(m.as_str())
    }
}

fn flash<E: NorFlashError>(e: E) -> StoreError {
    StoreError::Flash(e.kind())
}

/// A valid record found in the log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Found {
    /// Sector index.
    pub sector: usize,
    /// Offset of the record's header from the start of its sector, bytes.
    pub offset: u32,
    /// Generation (higher is newer).
    pub generation: u32,
    /// Payload length, bytes.
    pub len: usize,
}

/// What a scan of the log found: the newest record and where the next one goes.
#[derive(Clone, Copy, Debug)]
struct Cursor {
    newest: Option<Found>,
    /// Sector the next record is appended to, and the offset in it.
    sector: usize,
    offset: u32,
}

/// Outcome of reading one header.
enum Header {
    /// Not a committed record of any format (erased, cut short or damaged): ends the sector.
    End,
    /// A committed record of another format: refused; its length is unknown, ends the sector.
    Other(u16),
    /// A committed record: generation, payload length, payload CRC.
    Record(u32, usize, u32),
}

/// The checkpoint log over a NOR flash region (the whole of `F`'s capacity).
pub struct CheckpointStore<F> {
    flash: F,
    sectors: usize,
    sector_size: u32,
    cursor: Option<Cursor>,
}

impl<F: NorFlash> CheckpointStore<F> {
    /// A store over `flash`: its capacity in whole erase sectors (at least two).
    pub fn new(flash: F) -> Result<Self, StoreError> {
        let erase = F::ERASE_SIZE;
        if F::WRITE_SIZE > MAX_WRITE || !MAX_WRITE.is_multiple_of(F::WRITE_SIZE) || erase == 0 {
            return Err(StoreError::Geometry);
        }
        let sectors = flash.capacity() / erase;
        if sectors < 2 || erase < Self::record_size(0) {
            return Err(StoreError::Geometry);
        }
        Ok(CheckpointStore {
            flash,
            sectors,
            sector_size: erase as u32,
            cursor: None,
        })
    }

    /// Bytes a record with a `len`-byte payload takes in this flash (header and padding).
    pub const fn record_size(len: usize) -> usize {
        pad(HEADER, F::WRITE_SIZE) + pad(len, F::WRITE_SIZE)
    }

    /// Records with a `len`-byte payload that fit one erase sector.
    pub const fn records_per_sector(len: usize) -> usize {
        F::ERASE_SIZE / Self::record_size(len)
    }

    /// The flash (tests: inspect or damage it).
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    fn addr(&self, sector: usize, offset: u32) -> u32 {
        sector as u32 * self.sector_size + offset
    }

    fn header(&mut self, at: u32) -> Result<Header, StoreError> {
        let mut h = [0u8; HEADER];
        self.flash.read(at, &mut h).map_err(flash)?;
        let word = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        if word(0) != MAGIC || word(20) != CRC32.checksum(&h[..20]) {
            return Ok(Header::End);
        }
        let format = u16::from_le_bytes([h[4], h[5]]);
        if format != FORMAT {
            return Ok(Header::Other(format));
        }
        Ok(Header::Record(word(8), word(12) as usize, word(16)))
    }

    /// CRC of `len` flash bytes from `at`, read in small pieces (no payload-sized buffer).
    fn crc_of(&mut self, at: u32, len: usize) -> Result<u32, StoreError> {
        let mut d = CRC32.digest();
        let mut chunk = [0u8; 64];
        let mut off = 0;
        while off < len {
            let n = (len - off).min(chunk.len());
            self.flash
                .read(at + off as u32, &mut chunk[..n])
                .map_err(flash)?;
            d.update(&chunk[..n]);
            off += n;
        }
        Ok(d.finalize())
    }

    /// Whether `len` bytes from `at` are erased (all 0xFF).
    fn blank(&mut self, at: u32, len: usize) -> Result<bool, StoreError> {
        let mut chunk = [0u8; 64];
        let mut off = 0;
        while off < len {
            let n = (len - off).min(chunk.len());
            self.flash
                .read(at + off as u32, &mut chunk[..n])
                .map_err(flash)?;
            if chunk[..n].iter().any(|&b| b != 0xFF) {
                return Ok(false);
            }
            off += n;
        }
        Ok(true)
    }

    /// Walks every sector; returns the cursor and the format of refused records, if any.
    fn scan(&mut self) -> Result<(Cursor, Option<u16>), StoreError> {
        let hl = pad(HEADER, F::WRITE_SIZE) as u32;
        let mut newest: Option<Found> = None;
        let mut refused = None;
        // Where the walks of sector 0 and of the newest record's sector ended.
        let mut end_of_first = 0;
        let mut end_of_newest_sector = 0;
        for sector in 0..self.sectors {
            let mut offset = 0u32;
            while offset + hl <= self.sector_size {
                let at = self.addr(sector, offset);
                let (generation, len, crc) = match self.header(at)? {
                    Header::End => break,
                    Header::Other(format) => {
                        refused = Some(format);
                        break;
                    }
                    Header::Record(g, len, crc) => (g, len, crc),
                };
                let size = Self::record_size(len) as u32;
                if len > MAX_PAYLOAD || offset + size > self.sector_size {
                    break; // a header CRC collision on garbage: never trust what follows
                }
                if self.crc_of(at + hl, len)? == crc
                    && newest.is_none_or(|n| generation > n.generation)
                {
                    newest = Some(Found {
                        sector,
                        offset,
                        generation,
                        len,
                    });
                }
                offset += size;
            }
            if sector == 0 {
                end_of_first = offset;
            }
            if newest.is_some_and(|n| n.sector == sector) {
                end_of_newest_sector = offset;
            }
        }
        let (sector, offset) = match newest {
            Some(n) => (n.sector, end_of_newest_sector),
            None => (0, end_of_first),
        };
        Ok((
            Cursor {
                newest,
                sector,
                offset,
            },
            refused,
        ))
    }

    /// Loads the newest valid checkpoint into `buf`; `Ok(None)` when there is none. Records of
    /// another format are refused with [`StoreError::Format`] (only if no record is valid: a
    /// valid record wins).
    pub fn load(&mut self, buf: &mut [u8]) -> Result<Option<Found>, StoreError> {
        let (cursor, refused) = self.scan()?;
        self.cursor = Some(cursor);
        match (cursor.newest, refused) {
            (Some(f), _) => {
                let at = self.addr(f.sector, f.offset) + pad(HEADER, F::WRITE_SIZE) as u32;
                let dst = buf.get_mut(..f.len).ok_or(StoreError::TooLarge)?;
                self.flash.read(at, dst).map_err(flash)?;
                Ok(Some(f))
            }
            (None, Some(found)) => Err(StoreError::Format { found }),
            (None, None) => Ok(None),
        }
    }

    /// Appends `payload` as the next generation; returns the generation written. The first
    /// save (or [`CheckpointStore::load`]) scans the log to find where it ends.
    pub fn save(&mut self, payload: &[u8]) -> Result<u32, StoreError> {
        let size = Self::record_size(payload.len());
        if payload.len() > MAX_PAYLOAD || size as u32 > self.sector_size {
            return Err(StoreError::TooLarge);
        }
        let cursor = match self.cursor {
            Some(c) => c,
            None => self.scan()?.0,
        };
        // Until this record is committed, a failure must not leave a stale cursor behind.
        self.cursor = None;
        let (mut sector, mut offset) = (cursor.sector, cursor.offset);
        let fits = offset as usize + size <= self.sector_size as usize;
        if !fits || !self.blank(self.addr(sector, offset), size)? {
            // Full, or the remains of an interrupted append: continue in the next sector (the
            // oldest records), erased first.
            sector = (sector + 1) % self.sectors;
            offset = 0;
            let a = self.addr(sector, 0);
            self.flash.erase(a, a + self.sector_size).map_err(flash)?;
        }
        let generation = cursor.newest.map_or(1, |n| n.generation.wrapping_add(1));
        let base = self.addr(sector, offset);
        let hl = pad(HEADER, F::WRITE_SIZE);
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
        h[16..20].copy_from_slice(&CRC32.checksum(payload).to_le_bytes());
        let c = CRC32.checksum(&h[..20]);
        h[20..24].copy_from_slice(&c.to_le_bytes());
        self.flash.write(base, &h[..hl]).map_err(flash)?;
        let found = Found {
            sector,
            offset,
            generation,
            len: payload.len(),
        };
        self.cursor = Some(Cursor {
            newest: Some(found),
            sector,
            offset: offset + size as u32,
        });
        Ok(generation)
    }
}

const fn pad(n: usize, to: usize) -> usize {
    n.div_ceil(to) * to
}

/// NOR flash in RAM: `N` bytes, erase sectors of `SECTOR` bytes, writes of `WRITE` bytes
/// (default 8; the STM32H7 programs 32); enforces NOR semantics (a write may only program erased
/// bytes). For host tests, and for QEMU over a RAM region that survives a reset (see the QEMU
/// board).
pub struct RamFlash<'a, const SECTOR: usize, const WRITE: usize = 8> {
    mem: &'a mut [u8],
    /// Stop after this many more bytes written or erased (tests: a reset in the middle of a
    /// write or of an erase).
    pub fail_after_bytes: Option<usize>,
    /// Sector erases done so far (tests: flash wear).
    pub erases: u64,
}

impl<'a, const SECTOR: usize, const WRITE: usize> RamFlash<'a, SECTOR, WRITE> {
    /// Flash over `mem` (left as it is: it may hold checkpoints from before a reset).
    pub fn new(mem: &'a mut [u8]) -> Self {
        RamFlash {
            mem,
            fail_after_bytes: None,
            erases: 0,
        }
    }

    /// The bytes (tests).
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        self.mem
    }

    /// Counts one byte of a write or an erase against `fail_after_bytes`.
    fn spend(&mut self) -> Result<(), RamFlashError> {
        if let Some(n) = self.fail_after_bytes.as_mut() {
            if *n == 0 {
                return Err(RamFlashError::PowerLoss);
            }
            *n -= 1;
        }
        Ok(())
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

impl<const SECTOR: usize, const WRITE: usize> embedded_storage::nor_flash::ErrorType
    for RamFlash<'_, SECTOR, WRITE>
{
    type Error = RamFlashError;
}

impl<const SECTOR: usize, const WRITE: usize> ReadNorFlash for RamFlash<'_, SECTOR, WRITE> {
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

impl<const SECTOR: usize, const WRITE: usize> NorFlash for RamFlash<'_, SECTOR, WRITE> {
    const WRITE_SIZE: usize = WRITE;
    const ERASE_SIZE: usize = SECTOR;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let (a, b) = (from as usize, to as usize);
        if !a.is_multiple_of(SECTOR) || !b.is_multiple_of(SECTOR) || b > self.mem.len() || a > b {
            return Err(RamFlashError::OutOfBounds);
        }
        self.erases += ((b - a) / SECTOR) as u64;
        for i in a..b {
            self.spend()?;
            self.mem[i] = 0xFF;
        }
        Ok(())
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let o = offset as usize;
        if !o.is_multiple_of(WRITE)
            || !bytes.len().is_multiple_of(WRITE)
            || o + bytes.len() > self.mem.len()
        {
            return Err(RamFlashError::OutOfBounds);
        }
        for (i, &b) in bytes.iter().enumerate() {
            self.spend()?;
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
