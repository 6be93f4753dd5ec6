//! The resume block: what the application stores with the core's filter image in a checkpoint
//! payload, so a reset resumes the run at a window boundary. One layout, encoded and decoded
//! here only (little-endian):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 2 | block version, [`VERSION`] |
//! | 2 | 1 | source: 0 sensor, 1 replay, `0xFF` no run in progress ([`NO_RUN`]) |
//! | 3 | 1 | reserved, 0 |
//! | 4 | 4 | sequence number of the next sample to screen (u32) |
//! | 8 | 8 | time of the last sample screened, s (f64; NaN: none) |
//! | 16 | 2 | length `c` of the configuration (u16) |
//! | 18 | 2 | length `s` of the screening state (u16) |
//! | 20 | `c` | the run's [`Config`], postcard |
//! | 20 + `c` | `s` | the sample screening's state ([`Screen::save`]: the samples the core's screener holds) |
//! | 20 + `c` + `s` | rest | the estimator core's checkpoint image ([`estimator_core::checkpoint`]) |
//!
//! The checkpoint is taken after the update that a sample coming out of the screening closed;
//! that sample opened the next averaging window and is the screening's last sample out, so the
//! averager is rebuilt from it ([`Screen::last_accepted`]). The sequence number is the next
//! sample to feed the screening, the time the last one fed.
//!
//! A "no run" payload is the 20-byte block with source `0xFF` (written at the start and the end
//! of runs, so a reset never resumes a finished or abandoned run).

use estimator_core::checkpoint::CheckpointError;
use protocol::{Config, Source, STATE_DIM};

use crate::app::{validate, Filter};
use crate::screen::Screen;

/// Version of the resume block written by this code (2: with the screening state).
pub const VERSION: u16 = 2;
/// Source byte of a payload that says "no run in progress".
pub const NO_RUN: u8 = 0xFF;
/// Bytes before the configuration.
pub const FIXED: usize = 20;

const SOURCE: usize = 2;
const NEXT_SEQ: usize = 4;
const LAST_T: usize = 8;
const CFG_LEN: usize = 16;
const SCREEN_LEN: usize = 18;

/// Where a run can be resumed from: the next sample to screen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResumePoint {
    /// Sequence number of that sample.
    pub next_seq: u32,
    /// Time of the last sample screened before it (the resumed run accepts only later samples).
    pub last_t_s: Option<f64>,
}

/// Why a payload could not be encoded or restored (a short text for the fault frame).
pub type Error = &'static str;

/// Encodes a run's resume block, screening state and filter image into `buf`; returns the
/// payload length.
pub fn encode_run(
    buf: &mut [u8],
    source: Source,
    point: ResumePoint,
    config: &Config,
    screen: &Screen,
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
    let state = buf.get_mut(FIXED + c..).ok_or("buffer too small")?;
    let s = screen.save(state).ok_or("screening state does not fit")?;
    let s16 = u16::try_from(s).map_err(|_| "screening state too long")?;
    buf[SCREEN_LEN..SCREEN_LEN + 2].copy_from_slice(&s16.to_le_bytes());
    let image = buf.get_mut(FIXED + c + s..).ok_or("buffer too small")?;
    let n = ekf
        .checkpoint(image)
        .map_err(|_| "filter image does not fit")?;
    Ok(FIXED + c + s + n)
}

/// Encodes the "no run" payload into `buf`; returns its length ([`FIXED`]).
pub fn encode_no_run(buf: &mut [u8]) -> Result<usize, Error> {
    let head = buf.get_mut(..FIXED).ok_or("buffer too small")?;
    head.fill(0);
    head[..2].copy_from_slice(&VERSION.to_le_bytes());
    head[SOURCE] = NO_RUN;
    Ok(FIXED)
}

/// Bytes of a run's payload with configuration `config` (the 15-state filter; the screening
/// holding as many samples as it does in a run, which is where checkpoints are taken).
pub fn payload_len(config: &Config) -> Option<usize> {
    let mut buf = [0u8; 128];
    let c = postcard::to_slice(config, &mut buf).ok()?.len();
    Some(FIXED + c + Screen::state_len() + estimator_core::checkpoint::size(STATE_DIM))
}

/// A fault detail (truncated to the protocol's 80 bytes; written without `core::fmt`).
pub type Msg = protocol::Detail;

/// `prefix` followed by `what`.
pub fn msg(prefix: &str, what: &str) -> Msg {
    let mut m = Msg::from(prefix);
    m.text(what);
    m
}

/// A checkpoint error's text, as [`CheckpointError`]'s `Display` writes it (a test checks
/// they agree), without `core::fmt`.
pub fn describe_checkpoint_error(e: &CheckpointError, m: &mut Msg) {
    match *e {
        CheckpointError::BufferTooSmall { needed } => m
            .text("checkpoint needs ")
            .dec(u32::try_from(needed).unwrap_or(u32::MAX))
            .text(" bytes"),
        CheckpointError::Truncated => m.text("checkpoint truncated"),
        CheckpointError::BadMagic => m.text("not a checkpoint"),
        CheckpointError::Version { found, expected } => m
            .text("checkpoint format version ")
            .dec(found.into())
            .text(", this filter reads ")
            .dec(expected.into()),
        CheckpointError::ModelMismatch { found, expected } => m
            .text("checkpoint of another model configuration (fingerprint ")
            .hex(found, 8)
            .text(", this model ")
            .hex(expected, 8)
            .text(")"),
        CheckpointError::Crc => m.text("checkpoint damaged (CRC mismatch)"),
        CheckpointError::Invalid => m.text("checkpoint holds non-finite values"),
    };
}

/// A decoded resume block; the filter image is not loaded yet ([`load_filter`]).
pub struct Block<'a> {
    /// The run's source.
    pub source: Source,
    /// Where it resumes.
    pub point: ResumePoint,
    /// Its configuration (validated).
    pub config: Config,
    /// The screening's state ([`Screen::load`]).
    pub screen_state: &'a [u8],
    /// The estimator core's checkpoint image.
    pub image: &'a [u8],
}

/// Decodes a payload: `Ok(None)` for "no run", the block otherwise. `Err` says what is wrong
/// (another block version, a truncated block, a configuration refused).
pub fn decode(payload: &[u8]) -> Result<Option<Block<'_>>, Msg> {
    let bad = |what: &str| msg("checkpoint: ", what);
    let head = payload
        .get(..FIXED)
        .ok_or_else(|| bad("resume block truncated"))?;
    let version = u16::from_le_bytes([head[0], head[1]]);
    if version != VERSION {
        let mut m = msg("checkpoint resume block v", "");
        m.dec(version.into())
            .text(", firmware reads v")
            .dec(VERSION.into());
        return Err(m);
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
    let st = usize::from(u16::from_le_bytes([head[SCREEN_LEN], head[SCREEN_LEN + 1]]));
    let cfg_bytes = payload
        .get(FIXED..FIXED + c)
        .ok_or_else(|| bad("configuration truncated"))?;
    let config: Config =
        postcard::from_bytes(cfg_bytes).map_err(|_| bad("configuration unreadable"))?;
    validate(&config).map_err(|why| msg("checkpoint configuration refused: ", why))?;
    Ok(Some(Block {
        source,
        point: ResumePoint {
            next_seq: u32::from_le_bytes(seq),
            last_t_s: (!last.is_nan()).then_some(last),
        },
        config,
        screen_state: payload
            .get(FIXED + c..FIXED + c + st)
            .ok_or_else(|| bad("screening state truncated"))?,
        image: &payload[FIXED + c + st..],
    }))
}

/// Loads a block's filter image into `ekf`, a fresh filter of the block's configuration (in
/// place: the caller keeps one filter on its stack or in its state, not several).
pub fn load_filter(ekf: &mut Filter, image: &[u8]) -> Result<(), Msg> {
    ekf.resume(image).map_err(|e| {
        let mut m = Msg::new();
        describe_checkpoint_error(&e, &mut m);
        m
    })
}
