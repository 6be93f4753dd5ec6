//! Fuzzing the frame decoder on stable (proptest; `cargo fuzz` needs nightly and a corpus
//! directory, this runs in every `cargo test`): valid frame streams mutated (bit flips, byte
//! inserts and deletions, splices of two streams, arbitrary chunking) and pure random bytes.
//! Properties: no panic; every packet the decoder yields is bit-identical to one that was sent
//! (a CRC-32 collision would be needed otherwise); the decoder's counts add up. The decoder has
//! a fixed buffer (`MAX_FRAME`): memory cannot grow with the input, whatever it is.

use proptest::prelude::*;
use protocol::*;

fn sample(k: u32) -> Message {
    let t = f64::from(k);
    Message::Raw(RawSample {
        seq: k,
        t_s: t,
        specific_force: [t.sin(), t.cos(), 9.8],
        temp_c: 20.0 + t * 1e-3,
    })
}

fn estimate(k: u32) -> Message {
    Message::Estimate(Estimate {
        step: k,
        t_s: 60.0 * f64::from(k),
        samples: 60,
        state: [f64::from(k) * 1e-3; 15],
        sigma: [1e-4; 15],
        innovation: [1e-5, -2e-5, 3e-5],
        nis: 2.5,
    })
}

/// A stream of `n` frames (samples and estimates) and the packets in it.
fn stream(n: u32, first_seq: u32) -> (Vec<u8>, Vec<Packet>) {
    let mut bytes = Vec::new();
    let mut packets = Vec::new();
    for k in 0..n {
        let msg = if k % 5 == 4 { estimate(k) } else { sample(k) };
        let p = Packet::new(first_seq.wrapping_add(k), msg);
        let mut buf = [0u8; MAX_FRAME];
        bytes.extend_from_slice(encode(&p, &mut buf).unwrap());
        packets.push(p);
    }
    (bytes, packets)
}

#[derive(Clone, Debug)]
enum Mutation {
    Flip(usize, u8),
    Insert(usize, u8),
    Delete(usize),
    Splice(usize, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<usize>(), 0u8..8).prop_map(|(a, b)| Mutation::Flip(a, b)),
        (any::<usize>(), any::<u8>()).prop_map(|(a, b)| Mutation::Insert(a, b)),
        any::<usize>().prop_map(Mutation::Delete),
        (any::<usize>(), any::<usize>()).prop_map(|(a, b)| Mutation::Splice(a, b)),
    ]
}

fn decode_all(bytes: &[u8], chunk: usize) -> (Vec<Packet>, DecoderStats, u64) {
    let mut dec = Decoder::new();
    let mut got = Vec::new();
    let mut errors = 0u64;
    for c in bytes.chunks(chunk.max(1)) {
        dec.feed(c, |r| match r {
            Ok(p) => got.push(p),
            Err(_) => errors += 1,
        });
    }
    (got, *dec.stats(), errors)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4000, ..ProptestConfig::default() })]

    #[test]
    fn mutated_streams_never_panic_and_never_yield_a_packet_that_was_not_sent(
        n in 1u32..40,
        muts in proptest::collection::vec(mutation(), 0..12),
        chunk in 1usize..300,
    ) {
        let (mut bytes, sent) = stream(n, 7);
        let (other, other_sent) = stream(n, 1000);
        for m in &muts {
            let len = bytes.len().max(1);
            match *m {
                Mutation::Flip(a, b) => { let i = a % len; if i < bytes.len() { bytes[i] ^= 1 << b; } }
                Mutation::Insert(a, b) => bytes.insert(a % (bytes.len() + 1), b),
                Mutation::Delete(a) => { if !bytes.is_empty() { bytes.remove(a % len); } }
                Mutation::Splice(a, b) => {
                    // Cut this stream at a and continue with the other stream from b.
                    let a = a % (bytes.len() + 1);
                    let b = b % (other.len() + 1);
                    bytes.truncate(a);
                    bytes.extend_from_slice(&other[b..]);
                }
            }
        }
        let (got, stats, errors) = decode_all(&bytes, chunk);
        let same = |x: &Packet, y: &Packet| {
            let mut a = [0u8; MAX_PACKET];
            let mut b = [0u8; MAX_PACKET];
            postcard::to_slice(x, &mut a).unwrap() == postcard::to_slice(y, &mut b).unwrap()
        };
        for p in &got {
            prop_assert!(sent.iter().chain(&other_sent).any(|s| same(s, p)), "decoded a packet never sent: {:?}", p);
        }
        prop_assert_eq!(stats.ok, got.len() as u64);
        prop_assert_eq!(stats.bad(), errors);
        prop_assert_eq!(stats.bytes, bytes.len() as u64);
    }

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..4096), chunk in 1usize..500) {
        let (got, stats, errors) = decode_all(&bytes, chunk);
        // Random bytes pass COBS + version + postcard + CRC-32 only by a 2^-32 accident.
        prop_assert!(got.is_empty());
        prop_assert_eq!(stats.bad(), errors);
    }
}
