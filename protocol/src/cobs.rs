//! Consistent Overhead Byte Stuffing: removes every `0x00` from a block so `0x00` can delimit
//! frames. Overhead: one byte per 254 bytes of input, plus one.

/// Worst-case encoded length of `n` input bytes (without delimiters).
pub const fn max_encoded_len(n: usize) -> usize {
    n + n / 254 + 1
}

/// Encodes `src` into `dst` (no delimiter written); returns the encoded length, or `None` when
/// `dst` is too small.
pub fn encode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    if dst.len() < max_encoded_len(src.len()) {
        return None;
    }
    let mut code_at = 0;
    let mut out = 1;
    let mut code: u8 = 1;
    for &b in src {
        if b == 0 {
            dst[code_at] = code;
            code_at = out;
            out += 1;
            code = 1;
        } else {
            dst[out] = b;
            out += 1;
            code += 1;
            if code == 0xFF {
                dst[code_at] = code;
                code_at = out;
                out += 1;
                code = 1;
            }
        }
    }
    dst[code_at] = code;
    Some(out)
}

/// Streaming COBS decoder state for one frame (used by [`crate::Decoder`]).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Unstuffer {
    /// Data bytes left in the current block (0: the next byte is a code byte).
    remaining: u8,
    /// Code of the current block (0: no block started yet in this frame).
    code: u8,
}

/// What one non-zero input byte produces.
pub(crate) enum Unstuffed {
    /// Nothing to output (a code byte opening a block that follows a 0xFF block or starts the frame).
    None,
    /// One output byte.
    Byte(u8),
}

impl Unstuffer {
    pub(crate) fn reset(&mut self) {
        *self = Unstuffer::default();
    }

    /// Feeds one non-zero encoded byte. A code byte after a block shorter than 254 data bytes
    /// stands for the zero that block ended with.
    pub(crate) fn push(&mut self, b: u8) -> Unstuffed {
        debug_assert!(b != 0);
        if self.remaining == 0 {
            let implicit_zero = self.code != 0 && self.code != 0xFF;
            self.code = b;
            self.remaining = b - 1;
            if implicit_zero {
                Unstuffed::Byte(0)
            } else {
                Unstuffed::None
            }
        } else {
            self.remaining -= 1;
            Unstuffed::Byte(b)
        }
    }

    /// At the delimiter: a well-formed frame ends exactly at the end of a block.
    pub(crate) fn complete(&self) -> bool {
        self.remaining == 0 && self.code != 0
    }
}

/// Decodes one COBS block (no delimiters) into `dst`; returns the decoded length, or `None` if
/// the input is malformed (a zero byte, a block running past the end) or `dst` is too small.
pub fn decode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    let mut u = Unstuffer::default();
    let mut n = 0;
    for &b in src {
        if b == 0 {
            return None;
        }
        if let Unstuffed::Byte(v) = u.push(b) {
            *dst.get_mut(n)? = v;
            n += 1;
        }
    }
    u.complete().then_some(n)
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
