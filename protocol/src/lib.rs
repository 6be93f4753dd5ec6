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
//!
//! A `Ping` command as packet number 7, its postcard bytes, its frame, and back:
//!
//! ```
//! use protocol::{encode, Command, Decoder, Message, Packet, MAX_FRAME, MAX_PACKET};
//!
//! let ping = Packet::new(7, Message::Command(Command::Ping));
//! // postcard: version 2, sequence number 7 (a varint), variant 5 (Command), variant 5 (Ping).
//! let mut raw = [0u8; MAX_PACKET];
//! assert_eq!(postcard::to_slice(&ping, &mut raw).unwrap(), &[0x02, 0x07, 0x05, 0x05]);
//!
//! // The frame: delimiter, COBS(those 4 bytes ++ their CRC-32 0x831f01d8, little-endian), delimiter.
//! let mut buf = [0u8; MAX_FRAME];
//! let frame = encode(&ping, &mut buf).unwrap();
//! assert_eq!(frame, &[0x00, 0x09, 0x02, 0x07, 0x05, 0x05, 0xd8, 0x01, 0x1f, 0x83, 0x00]);
//!
//! let mut decoder = Decoder::new();
//! let mut got = None;
//! decoder.feed(frame, |r| got = Some(r));
//! assert_eq!(got, Some(Ok(ping)));
//! assert_eq!(decoder.stats().bad(), 0);
//! ```
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

/// Bytes of the CRC-32 after the serialised packet.
pub const CRC_BYTES: usize = 4;

/// Largest serialised packet including its CRC, bytes: postcard's bound for the largest
/// [`Packet`] (an [`Estimate`]'s, 297 bytes; the `packet_size_bound_is_reached` test builds it).
pub const MAX_PACKET: usize =
    <Packet as postcard::experimental::max_size::MaxSize>::POSTCARD_MAX_SIZE + CRC_BYTES;

/// Largest frame on the wire: COBS overhead (1 byte per 254) plus the two delimiters.
pub const MAX_FRAME: usize = MAX_PACKET + MAX_PACKET / 254 + 1 + 2;

/// CRC-32 (ISO-HDLC, the Ethernet/zip polynomial) over the serialised packet.
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
