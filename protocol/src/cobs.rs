//! Consistent Overhead Byte Stuffing, from the [`cobs`](https://docs.rs/cobs) crate (the one
//! postcard already depends on): removes every `0x00` from a block so `0x00` can delimit frames.
//! Overhead: one byte per 254 bytes of input, plus one.
//!
//! This module only adapts the crate to the frame decoder: the crate's streaming
//! [`cobs::DecoderState`] does the unstuffing; loss counting, the fixed buffer and
//! resynchronisation on the next delimiter are the [`crate::Decoder`]'s (the crate's
//! `CobsDecoder` accumulator has neither counts nor a frame-at-a-time error model).

/// Worst-case encoded length of `n` input bytes (without delimiters).
pub const fn max_encoded_len(n: usize) -> usize {
    ::cobs::max_encoding_length(n)
}

/// Encodes `src` into `dst` (no delimiter written); returns the encoded length, or `None` when
/// `dst` is too small.
pub fn encode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    if src.is_empty() {
        // The crate encodes nothing as nothing; the canonical encoding is one code byte (a
        // frame is never empty: a packet has at least its version and CRC).
        *dst.first_mut()? = 1;
        return Some(1);
    }
    ::cobs::try_encode(src, dst).ok()
}

/// Decodes one COBS block (no delimiters) into `dst`; returns the decoded length, or `None` if
/// the input is malformed (a zero byte, a block running past the end) or `dst` is too small.
pub fn decode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    if src.contains(&0) {
        return None;
    }
    let mut u = Unstuffer::default();
    let mut n = 0;
    for &b in src {
        if let Some(v) = u.push(b) {
            *dst.get_mut(n)? = v;
            n += 1;
        }
    }
    u.complete().then_some(n)
}

/// Streaming unstuffing of one frame's non-zero bytes over [`cobs::DecoderState`].
#[derive(Debug)]
pub(crate) struct Unstuffer {
    state: ::cobs::DecoderState,
    /// A byte was refused (a zero inside a block cannot occur: zeros are the frame
    /// delimiters the caller handles; kept so a future crate change cannot go unnoticed).
    broken: bool,
}

impl Clone for Unstuffer {
    fn clone(&self) -> Self {
        use ::cobs::DecoderState::{Grab, GrabChain, Idle};
        // Not a needless match: the crate's DecoderState is not Clone, so it is rebuilt.
        #[allow(clippy::needless_match)]
        let state = match self.state {
            Idle => Idle,
            Grab(n) => Grab(n),
            GrabChain(n) => GrabChain(n),
        };
        Unstuffer {
            state,
            broken: self.broken,
        }
    }
}

impl Default for Unstuffer {
    fn default() -> Self {
        Unstuffer {
            state: ::cobs::DecoderState::Idle,
            broken: false,
        }
    }
}

impl Unstuffer {
    pub(crate) fn reset(&mut self) {
        *self = Unstuffer::default();
    }

    /// Feeds one non-zero encoded byte; returns the decoded byte it yields, if any.
    pub(crate) fn push(&mut self, b: u8) -> Option<u8> {
        debug_assert!(b != 0);
        match self.state.feed(b) {
            Ok(::cobs::DecodeResult::DataContinue(v)) => Some(v),
            Ok(_) => None,
            Err(_) => {
                self.broken = true;
                None
            }
        }
    }

    /// At the delimiter: a well-formed frame ends exactly at the end of a block (the crate's
    /// state machine reports `DataComplete` for the delimiter only then). Does not change the
    /// state: call [`Unstuffer::reset`] for the next frame.
    pub(crate) fn complete(&self) -> bool {
        !self.broken
            && matches!(
                self.state,
                ::cobs::DecoderState::Grab(0) | ::cobs::DecoderState::GrabChain(0)
            )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_vectors() {
        let cases: &[(&[u8], &[u8])] = &[
            (&[], &[1]),
            (&[0], &[1, 1]),
            (&[0, 0], &[1, 1, 1]),
            (&[0x11, 0x22, 0x00, 0x33], &[3, 0x11, 0x22, 2, 0x33]),
            (&[0x11, 0x00, 0x00, 0x00], &[2, 0x11, 1, 1, 1]),
        ];
        for (raw, enc) in cases {
            let mut buf = [0u8; 16];
            let n = encode(raw, &mut buf).unwrap();
            assert_eq!(&buf[..n], *enc, "encode {raw:?}");
            let mut back = [0u8; 16];
            let m = decode(enc, &mut back).unwrap();
            assert_eq!(&back[..m], *raw, "decode {enc:?}");
        }
    }

    #[test]
    fn malformed_blocks_are_refused() {
        let mut back = [0u8; 16];
        // A code byte promising 3 data bytes, only 1 present: the frame ends inside a block.
        assert_eq!(decode(&[4, 0x11], &mut back), None);
        // A zero inside the block.
        assert_eq!(decode(&[3, 0x11, 0, 0x22], &mut back), None);
        // An empty block is not a frame.
        assert_eq!(decode(&[], &mut back), None);
        // Output too small.
        assert_eq!(decode(&[5, 1, 2, 3, 4], &mut back[..2]), None);
    }

    #[test]
    fn long_runs_without_zero() {
        for len in [253usize, 254, 255, 508, 509, 600] {
            let raw: [u8; 600] = core::array::from_fn(|i| (i % 255 + 1) as u8);
            let raw = &raw[..len];
            let mut enc = [0u8; 700];
            let n = encode(raw, &mut enc).unwrap();
            assert!(n <= max_encoded_len(len));
            assert!(enc[..n].iter().all(|&b| b != 0));
            let mut back = [0u8; 700];
            let m = decode(&enc[..n], &mut back).unwrap();
            assert_eq!(&back[..m], raw, "len {len}");
        }
    }
}
