//! # protocol — the telemetry link between the navigation computer and `driftid`
//!
//! One versioned message enum ([`Message`]) carried in a [`Packet`] (protocol version, link
//! sequence number, message), serialised with postcard, followed by a CRC-32 of the serialised
//! bytes, COBS-encoded and framed by a `0x00` delimiter on **both** sides:
//!
//! ```text
//!  0x00 | COBS( postcard(Packet) ++ crc32_le(postcard(Packet)) ) | 0x00
//! ```
//!
//! Why a delimiter on both sides: if a frame is truncated (its tail and closing delimiter lost),
//! the next frame's opening delimiter ends the damaged one, so the damage costs that frame only.
//! Consecutive delimiters are empty frames and ignored silently. The [`Decoder`] is a streaming,
//! byte-at-a-time state machine over a fixed buffer: a corrupted, truncated or oversized frame is
//! counted in [`DecoderStats`] and the decoder resynchronises on the next delimiter. Sequence
//! numbers ([`SeqTracker`]) expose frames that vanished entirely.
//!
//! `no_std`, no allocation: every buffer is a fixed array ([`MAX_PACKET`], [`MAX_FRAME`]).
#![no_std]
#![warn(missing_docs)]

#[cfg(feature = "std")]
extern crate std;

pub mod cobs;
mod frame;
mod messages;
mod seq;

pub use frame::{encode, DecodeError, Decoder, DecoderStats, EncodeError, Encoder};
pub use messages::*;
pub use seq::{SeqEvent, SeqTracker};

/// Version of the wire protocol, the first byte of every packet. Bump it on any change of
/// [`Message`] or of the framing; a decoder refuses packets of another version (counted).
pub const PROTOCOL_VERSION: u8 = 2;

/// Number of filter states carried in an [`Estimate`] (the paper's model: 3 angles + 12 coefficients).
pub const STATE_DIM: usize = 15;

/// Largest serialised packet including its 4-byte CRC, bytes. The largest message, an
/// [`Estimate`], takes ≤ 1 + 5 + 1 + 5 + 8 + 5 + 120 + 120 + 24 + 8 = 297 bytes + 4 CRC.
pub const MAX_PACKET: usize = 384;

/// Largest frame on the wire: COBS overhead (1 byte per 254) plus the two delimiters.
pub const MAX_FRAME: usize = MAX_PACKET + MAX_PACKET / 254 + 1 + 2;

/// CRC-32 (ISO-HDLC, the Ethernet/zip polynomial) over the serialised packet.
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
