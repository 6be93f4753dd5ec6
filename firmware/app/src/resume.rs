//! The resume block: what the application stores with the core's filter image in a checkpoint
//! payload, so a reset resumes the run at a window boundary. One layout, encoded and decoded
//! here only (little-endian):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 2 | block version, [`VERSION`] |
//! | 2 | 1 | source: 0 sensor, 1 replay, `0xFF` no run in progress ([`NO_RUN`]) |
//! | 3 | 1 | reserved, 0 |
//! | 4 | 4 | sequence number of the sample that opened the current window (u32) |
//! | 8 | 8 | time of the last sample before it, s (f64; NaN: none) |
//! | 16 | 2 | length `c` of the configuration (u16) |
//! | 18 | 2 | reserved, 0 |
//! | 20 | `c` | the run's [`Config`], postcard |
//! | 20 + `c` | rest | the estimator core's checkpoint image ([`estimator_core::checkpoint`]) |
//!
//! A "no run" payload is the 20-byte block with source `0xFF` (written at the start and the end
//! of runs, so a reset never resumes a finished or abandoned run).

use protocol::{Config, Source, STATE_DIM};

use crate::app::{filter_for, validate, Filter};

/// Version of the resume block written by this code.
pub const VERSION: u16 = 1;
/// Source byte of a payload that says "no run in progress".
pub const NO_RUN: u8 = 0xFF;
/// Bytes before the configuration.
pub const FIXED: usize = 20;

const SOURCE: usize = 2;
const NEXT_SEQ: usize = 4;
const LAST_T: usize = 8;
const CFG_LEN: usize = 16;

/// Where a run can be resumed from: the sample that opened the current averaging window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResumePoint {
    /// Sequence number of that sample.
    pub next_seq: u32,
    /// Time of the last sample before it (the resumed run accepts only later samples).
    pub last_t_s: Option<f64>,
}

/// A decoded resume block with its filter, ready to run.
pub struct Restored {
    /// The run's source.
    pub source: Source,
    /// Where it resumes.
    pub point: ResumePoint,
    /// Its configuration (validated).
    pub config: Config,
    /// The filter, restored from the image.
    pub ekf: Filter,
}

/// Why a payload could not be encoded or restored (a short text for the fault frame).
pub type Error = &'static str;

/// Encodes a run's resume block and filter image into `buf`; returns the payload length.
pub fn encode_run(
    buf: &mut [u8],
    source: Source,
    point: ResumePoint,
    config: &Config,
    ekf: &Filter,
) -> Result<usize, Error> {
    let head = buf.get_mut(..FIXED).ok_or("buffer too small")?;
    head.fill(0);
    head[..2].copy_from_slice(&VERSION.to_le_bytes());
    head[SOURCE] = match source {
        Source::Sensor => 0,
        Source::Replay => 1,
    };
    head[NEXT_SEQ..NEXT_SEQ + 4].copy_from_slice(&point.next_seq.to_le_bytes());
    head[LAST_T..LAST_T + 8].copy_from_slice(&point.last_t_s.unwrap_or(f64::NAN).to_le_bytes());
    let tail = buf.get_mut(FIXED..).ok_or("buffer too small")?;
    let c = postcard::to_slice(config, tail)
        .map_err(|_| "configuration does not fit")?
        .len();
    let c16 = u16::try_from(c).map_err(|_| "configuration too long")?;
    buf[CFG_LEN..CFG_LEN + 2].copy_from_slice(&c16.to_le_bytes());
    let image = buf.get_mut(FIXED + c..).ok_or("buffer too small")?;
    let n = ekf
        .checkpoint(image)
        .map_err(|_| "filter image does not fit")?;
    Ok(FIXED + c + n)
}

/// Encodes the "no run" payload into `buf`; returns its length ([`FIXED`]).
pub fn encode_no_run(buf: &mut [u8]) -> Result<usize, Error> {
    let head = buf.get_mut(..FIXED).ok_or("buffer too small")?;
    head.fill(0);
    head[..2].copy_from_slice(&VERSION.to_le_bytes());
    head[SOURCE] = NO_RUN;
    Ok(FIXED)
}

/// Bytes of a run's payload with configuration `config` (the 15-state filter).
pub fn payload_len(config: &Config) -> Option<usize> {
    let mut buf = [0u8; 128];
    let c = postcard::to_slice(config, &mut buf).ok()?.len();
    Some(FIXED + c + estimator_core::checkpoint::size(STATE_DIM))
}

/// A fault detail (truncated to the protocol's 80 bytes).
pub type Msg = heapless::String<80>;

/// Formats into a [`Msg`], truncating what does not fit.
pub fn msg(args: core::fmt::Arguments<'_>) -> Msg {
    let mut s = Msg::new();
    let _ = core::fmt::write(&mut s, args);
    s
}

/// A decoded resume block; the filter image is not loaded yet ([`load_filter`]).
pub struct Block<'a> {
    /// The run's source.
    pub source: Source,
    /// Where it resumes.
    pub point: ResumePoint,
    /// Its configuration (validated).
    pub config: Config,
    /// The estimator core's checkpoint image.
    pub image: &'a [u8],
}

/// Decodes a payload: `Ok(None)` for "no run", the block otherwise. `Err` says what is wrong
/// (another block version, a truncated block, a configuration refused).
pub fn decode(payload: &[u8]) -> Result<Option<Block<'_>>, Msg> {
    let bad = |what: &str| msg(format_args!("checkpoint: {what}"));
    let head = payload
        .get(..FIXED)
        .ok_or_else(|| bad("resume block truncated"))?;
    let version = u16::from_le_bytes([head[0], head[1]]);
    if version != VERSION {
        return Err(msg(format_args!(
            "checkpoint resume block v{version}, firmware reads v{VERSION}"
        )));
    }
    let source = match head[SOURCE] {
        NO_RUN => return Ok(None),
        0 => Source::Sensor,
        1 => Source::Replay,
        _ => return Err(bad("unknown source")),
    };
    let mut seq = [0u8; 4];
    seq.copy_from_slice(&head[NEXT_SEQ..NEXT_SEQ + 4]);
    let mut t = [0u8; 8];
    t.copy_from_slice(&head[LAST_T..LAST_T + 8]);
    let last = f64::from_le_bytes(t);
    let c = usize::from(u16::from_le_bytes([head[CFG_LEN], head[CFG_LEN + 1]]));
    let cfg_bytes = payload
        .get(FIXED..FIXED + c)
        .ok_or_else(|| bad("configuration truncated"))?;
    let config: Config =
        postcard::from_bytes(cfg_bytes).map_err(|_| bad("configuration unreadable"))?;
    validate(&config)
        .map_err(|why| msg(format_args!("checkpoint configuration refused: {why}")))?;
    Ok(Some(Block {
        source,
        point: ResumePoint {
            next_seq: u32::from_le_bytes(seq),
            last_t_s: (!last.is_nan()).then_some(last),
        },
        config,
        image: &payload[FIXED + c..],
    }))
}

/// Loads a block's filter image into `ekf`, a fresh filter of the block's configuration (in
/// place: the caller keeps one filter on its stack or in its state, not several).
pub fn load_filter(ekf: &mut Filter, image: &[u8]) -> Result<(), Msg> {
    ekf.resume(image).map_err(|e| msg(format_args!("{e}")))
}

/// [`decode`], then a filter of the block's configuration restored from its image.
pub fn restore(payload: &[u8]) -> Result<Option<Restored>, Msg> {
    let Some(b) = decode(payload)? else {
        return Ok(None);
    };
    let mut ekf = filter_for(&b.config).map_err(|why| msg(format_args!("checkpoint: {why}")))?;
    load_filter(&mut ekf, b.image)?;
    Ok(Some(Restored {
        source: b.source,
        point: b.point,
        config: b.config,
        ekf,
    }))
}
