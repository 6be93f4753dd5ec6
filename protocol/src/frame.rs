//! Framing: postcard + CRC-32 + COBS + delimiters, and the streaming decoder.

use crate::cobs::{self, Unstuffer};
use crate::{Message, Packet, CRC, CRC_BYTES, MAX_FRAME, MAX_PACKET, PROTOCOL_VERSION};

/// Why a packet could not be framed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EncodeError {
    /// The packet does not fit [`MAX_PACKET`] (or the output buffer).
    TooLarge,
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "packet larger than {MAX_PACKET} bytes")
    }
}

#[cfg(feature = "std")]
impl std::error::Error for EncodeError {}

/// Frames `packet` into `out` (≥ [`MAX_FRAME`] bytes is always enough): returns the frame,
/// delimiters included.
pub fn encode<'a>(packet: &Packet, out: &'a mut [u8]) -> Result<&'a [u8], EncodeError> {
    let mut raw = [0u8; MAX_PACKET];
    let n = postcard::to_slice(packet, &mut raw[..MAX_PACKET - CRC_BYTES])
        .map_err(|_| EncodeError::TooLarge)?
        .len();
    let crc = CRC.checksum(&raw[..n]);
    raw[n..n + CRC_BYTES].copy_from_slice(&crc.to_le_bytes());
    let body = n + 4;
    if out.len() < cobs::max_encoded_len(body) + 2 {
        return Err(EncodeError::TooLarge);
    }
    out[0] = 0;
    let m = cobs::encode(&raw[..body], &mut out[1..]).ok_or(EncodeError::TooLarge)?;
    out[m + 1] = 0;
    Ok(&out[..m + 2])
}

/// A sender: numbers its packets and frames them into its own buffer.
#[derive(Clone, Debug)]
pub struct Encoder {
    seq: u32,
    buf: [u8; MAX_FRAME],
}

impl Default for Encoder {
    fn default() -> Self {
        Encoder {
            seq: 0,
            buf: [0; MAX_FRAME],
        }
    }
}

impl Encoder {
    /// A sender starting at sequence number 0.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sequence number the next frame will carry.
    pub fn next_seq(&self) -> u32 {
        self.seq
    }

    /// Frames `msg` with the next sequence number; returns the bytes to send.
    pub fn frame(&mut self, msg: Message) -> Result<&[u8], EncodeError> {
        let p = Packet::new(self.seq, msg);
        self.seq = self.seq.wrapping_add(1);
        encode(&p, &mut self.buf)
    }
}

/// Why a frame was dropped by the decoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// More than [`MAX_PACKET`] bytes before the delimiter.
    Overflow,
    /// The frame ended inside a COBS block (truncated or corrupted code byte).
    Cobs,
    /// Shorter than a CRC.
    TooShort,
    /// CRC mismatch.
    Crc,
    /// CRC good, but another protocol version.
    Version(u8),
    /// CRC good, version good, but postcard could not read the message (or trailing bytes).
    Malformed,
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DecodeError::Overflow => write!(f, "frame longer than {MAX_PACKET} bytes"),
            DecodeError::Cobs => write!(f, "frame truncated or COBS-corrupted"),
            DecodeError::TooShort => write!(f, "frame shorter than its CRC"),
            DecodeError::Crc => write!(f, "CRC mismatch"),
            DecodeError::Version(v) => {
                write!(f, "protocol version {v}, expected {PROTOCOL_VERSION}")
            }
            DecodeError::Malformed => write!(f, "malformed message"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for DecodeError {}

/// What the decoder has seen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Frames decoded.
    pub ok: u64,
    /// Frames dropped because they overflowed the buffer.
    pub overflow: u64,
    /// Frames dropped for a COBS error (truncated block).
    pub cobs: u64,
    /// Frames dropped for a CRC mismatch or being too short to hold one.
    pub crc: u64,
    /// Frames of another protocol version.
    pub version: u64,
    /// Frames whose CRC held but whose content did not parse.
    pub malformed: u64,
    /// Bytes received (delimiters included).
    pub bytes: u64,
}

impl DecoderStats {
    /// All frames dropped, whatever the reason.
    pub fn bad(&self) -> u64 {
        self.overflow + self.cobs + self.crc + self.version + self.malformed
    }
}

/// Streaming frame decoder over a fixed buffer: feed it bytes as they arrive.
///
/// Every non-empty run of bytes between two delimiters yields exactly one result: a packet or
/// the reason it was dropped. Nothing a damaged frame contains can affect the next frame.
#[derive(Clone, Debug)]
pub struct Decoder {
    buf: [u8; MAX_PACKET],
    len: usize,
    /// Bytes seen in the current frame (0: between frames).
    seen: usize,
    overflow: bool,
    unstuff: Unstuffer,
    stats: DecoderStats,
}

impl Default for Decoder {
    fn default() -> Self {
        Decoder {
            buf: [0; MAX_PACKET],
            len: 0,
            seen: 0,
            overflow: false,
            unstuff: Unstuffer::default(),
            stats: DecoderStats::default(),
        }
    }
}

impl Decoder {
    /// A decoder waiting for a delimiter or a frame.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counts so far.
    pub fn stats(&self) -> &DecoderStats {
        &self.stats
    }

    /// Feeds one byte; returns a result when the byte ends a non-empty frame.
    pub fn push(&mut self, byte: u8) -> Option<Result<Packet, DecodeError>> {
        self.push_as(byte)
    }

    /// [`Decoder::push`], the packet decoded as `P` (the firmware: [`crate::CommandPacket`]; a
    /// packet that is not a `P` is [`DecodeError::Malformed`]).
    pub fn push_as<P: serde::de::DeserializeOwned>(
        &mut self,
        byte: u8,
    ) -> Option<Result<P, DecodeError>> {
        self.stats.bytes += 1;
        if byte == 0 {
            if self.seen == 0 {
                return None; // empty frame: two delimiters in a row
            }
            let r = self.finish();
            match r {
                Ok(_) => self.stats.ok += 1,
                Err(DecodeError::Overflow) => self.stats.overflow += 1,
                Err(DecodeError::Cobs) => self.stats.cobs += 1,
                Err(DecodeError::TooShort | DecodeError::Crc) => self.stats.crc += 1,
                Err(DecodeError::Version(_)) => self.stats.version += 1,
                Err(DecodeError::Malformed) => self.stats.malformed += 1,
            }
            self.len = 0;
            self.seen = 0;
            self.overflow = false;
            self.unstuff.reset();
            return Some(r);
        }
        self.seen += 1;
        if self.overflow {
            return None;
        }
        if let Some(v) = self.unstuff.push(byte) {
            if self.len == MAX_PACKET {
                self.overflow = true;
            } else {
                self.buf[self.len] = v;
                self.len += 1;
            }
        }
        None
    }

    /// Feeds a slice; calls `f` for every frame result, in order.
    pub fn feed(&mut self, bytes: &[u8], mut f: impl FnMut(Result<Packet, DecodeError>)) {
        for &b in bytes {
            if let Some(r) = self.push(b) {
                f(r);
            }
        }
    }

    fn finish<P: serde::de::DeserializeOwned>(&self) -> Result<P, DecodeError> {
        if self.overflow {
            return Err(DecodeError::Overflow);
        }
        if !self.unstuff.complete() {
            return Err(DecodeError::Cobs);
        }
        if self.len < 5 {
            return Err(DecodeError::TooShort);
        }
        let (body, crc) = self.buf[..self.len].split_at(self.len - 4);
        if CRC.checksum(body).to_le_bytes() != crc {
            return Err(DecodeError::Crc);
        }
        if body[0] != PROTOCOL_VERSION {
            return Err(DecodeError::Version(body[0]));
        }
        match postcard::take_from_bytes::<P>(body) {
            Ok((p, [])) => Ok(p),
            _ => Err(DecodeError::Malformed),
        }
    }
}
