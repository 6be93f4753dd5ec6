//! Property tests of the codec: every message round-trips bit-exactly; random damage to a frame
//! costs that frame only, and is counted.

use proptest::prelude::*;
use protocol::*;

fn f64_any() -> impl Strategy<Value = f64> {
    // Any bit pattern, NaNs and infinities included: the link must carry them unchanged.
    prop_oneof![any::<u64>().prop_map(f64::from_bits), -1e3f64..1e3]
}

fn arr<const N: usize>() -> impl Strategy<Value = [f64; N]> {
    proptest::collection::vec(f64_any(), N).prop_map(|v| <[f64; N]>::try_from(v).unwrap())
}

fn raw() -> impl Strategy<Value = RawSample> {
    (any::<u32>(), f64_any(), arr::<3>(), f64_any()).prop_map(
        |(seq, t_s, specific_force, temp_c)| RawSample {
            seq,
            t_s,
            specific_force,
            temp_c,
        },
    )
}

fn config() -> impl Strategy<Value = Config> {
    (
        f64_any(),
        f64_any(),
        proptest::option::of(f64_any()),
        arr::<3>(),
        f64_any(),
        any::<bool>(),
        any::<u32>(),
    )
        .prop_map(|(p, lat, g, s, arw, echo, every)| Config {
            filter_period_s: p,
            latitude_deg: lat,
            gravity_mps2: g,
            raw_sigma_mps2: s,
            arw_deg2_per_h: arw,
            echo_raw: echo,
            status_every: every,
            checkpoint_every: every.rotate_left(7),
            gate_nis: f64::from(every % 100),
            ..Config::default()
        })
}

fn counters() -> impl Strategy<Value = Counters> {
    proptest::collection::vec(any::<u32>(), 20).prop_map(|v| Counters {
        samples_ok: v[0],
        samples_nan: v[1],
        samples_saturated: v[2],
        read_errors: v[3],
        samples_out_of_order: v[4],
        filter_steps: v[5],
        filter_errors: v[6],
        frames_rx: v[7],
        frames_rx_bad: v[8],
        frames_rx_missing: v[9],
        commands_refused: v[10],
        frames_tx: v[11],
        checkpoints_written: v[12],
        checkpoint_errors: v[13],
        samples_resync: v[14],
        samples_duplicate: v[15],
        samples_stuck: v[16],
        updates_rejected: v[17],
        samples_glitch: v[18],
        samples_dropout: v[19],
    })
}

fn message() -> impl Strategy<Value = Message> {
    let estimate = (
        any::<u32>(),
        f64_any(),
        any::<u32>(),
        arr::<15>(),
        arr::<15>(),
        arr::<3>(),
        f64_any(),
    )
        .prop_map(|(step, t_s, samples, state, sigma, innovation, nis)| {
            Message::Estimate(Estimate {
                step,
                t_s,
                samples,
                state,
                sigma,
                innovation,
                nis,
            })
        });
    let resume = proptest::option::of((any::<[u32; 3]>(), f64_any()).prop_map(|(r, t_s)| Resume {
        step: r[0],
        t_s,
        next_seq: r[1],
        generation: r[2],
    }));
    let status = (
        f64_any(),
        any::<bool>(),
        counters(),
        any::<[u32; 5]>(),
        resume,
    )
        .prop_map(|(t_s, running, counters, r, resumed)| {
            Message::Status(Status {
                t_s,
                running,
                source: if running {
                    Source::Sensor
                } else {
                    Source::Replay
                },
                counters,
                stack_used_bytes: r[0],
                stack_size_bytes: r[1],
                static_ram_bytes: r[2],
                last_step_ticks: r[3],
                tick_hz: r[4],
                boot: r[0] % 2 == 0,
                resumed,
            })
        });
    let command = prop_oneof![
        config().prop_map(Command::Configure),
        Just(Command::Start(Source::Replay)),
        Just(Command::Start(Source::Sensor)),
        raw().prop_map(Command::Replay),
        Just(Command::Finish),
        Just(Command::Stop),
        Just(Command::Ping),
        Just(Command::Shutdown),
    ];
    prop_oneof![
        config().prop_map(|config| Message::Hello(Hello {
            board: Board::QemuMps2An500,
            firmware: [0, 1, 2],
            state_dim: 15,
            config
        })),
        raw().prop_map(Message::Raw),
        estimate,
        status,
        ("\\PC{0,100}", any::<u32>()).prop_map(|(s, step)| Message::Fault(Fault::new(
            FaultCode::Panic,
            step,
            format_args!("{s}")
        ))),
        command.prop_map(Message::Command),
    ]
}

/// Bit-exact comparison (NaN payloads included).
fn same(a: &Packet, b: &Packet) -> bool {
    let mut x = [0u8; MAX_PACKET];
    let mut y = [0u8; MAX_PACKET];
    postcard::to_slice(a, &mut x).unwrap() == postcard::to_slice(b, &mut y).unwrap()
}

fn frame_of(p: &Packet) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME];
    encode(p, &mut buf).unwrap().to_vec()
}

#[derive(Clone, Debug)]
enum Damage {
    /// Flip bit `bit` of byte `at` (inside the frame, delimiters excluded).
    Flip { at: usize, bit: u8 },
    /// Drop byte `at`.
    Drop { at: usize },
    /// Cut the frame after `keep` bytes (closing delimiter lost too).
    Truncate { keep: usize },
    /// Insert a random byte.
    Insert { at: usize, byte: u8 },
    /// The whole frame vanishes (a dropout): only the sequence numbers can tell.
    Vanish,
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        (any::<usize>(), 0u8..8).prop_map(|(at, bit)| Damage::Flip { at, bit }),
        any::<usize>().prop_map(|at| Damage::Drop { at }),
        any::<usize>().prop_map(|keep| Damage::Truncate { keep }),
        (any::<usize>(), any::<u8>()).prop_map(|(at, byte)| Damage::Insert { at, byte }),
        Just(Damage::Vanish),
    ]
}

/// Applies `d` to the frame `f` (opening delimiter at 0, closing at len-1; damage stays inside).
fn apply(f: &mut Vec<u8>, d: &Damage) {
    let inner = f.len() - 2;
    match *d {
        Damage::Flip { at, bit } => f[1 + at % inner] ^= 1 << bit,
        Damage::Drop { at } => {
            f.remove(1 + at % inner);
        }
        Damage::Truncate { keep } => f.truncate(2 + keep % (inner - 1)),
        Damage::Insert { at, byte } => f.insert(1 + at % (inner + 1), byte),
        Damage::Vanish => f.clear(),
    }
}

/// `f` with every run of delimiters shortened to one delimiter.
fn collapse_delimiters(f: &[u8]) -> Vec<u8> {
    let mut out: Vec<u8> = Vec::with_capacity(f.len());
    for &b in f {
        if !(b == 0 && out.last() == Some(&0)) {
            out.push(b);
        }
    }
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn round_trip(msg in message(), seq in any::<u32>()) {
        let p = Packet::new(seq, msg);
        let f = frame_of(&p);
        prop_assert!(f.len() <= MAX_FRAME);
        prop_assert_eq!(f[0], 0);
        prop_assert_eq!(*f.last().unwrap(), 0);
        prop_assert!(f[1..f.len() - 1].iter().all(|&b| b != 0));
        let mut d = Decoder::new();
        let mut out = Vec::new();
        d.feed(&f, |r| out.push(r));
        prop_assert_eq!(out.len(), 1);
        let got = out.pop().unwrap().unwrap();
        prop_assert!(same(&got, &p));
        prop_assert_eq!(d.stats().ok, 1);
        prop_assert_eq!(d.stats().bad(), 0);
    }

    /// The firmware's decoding (commands only): every command decodes to itself, with its
    /// sequence number; every other message is a malformed frame, counted as such.
    #[test]
    fn the_firmware_decodes_commands_only(msg in message(), seq in any::<u32>()) {
        let p = Packet::new(seq, msg.clone());
        let mut d = Decoder::new();
        let mut out = Vec::new();
        for b in frame_of(&p) {
            if let Some(r) = d.push_as::<CommandPacket>(b) {
                out.push(r);
            }
        }
        prop_assert_eq!(out.len(), 1);
        match (msg, out.pop().unwrap()) {
            (Message::Command(c), Ok(got)) => {
                prop_assert_eq!(got.seq, seq);
                let Inbound::Command(g) = got.msg;
                prop_assert_eq!(format!("{g:?}"), format!("{c:?}"));
            }
            (Message::Command(_), Err(e)) => prop_assert!(false, "command refused: {e:?}"),
            (_, r) => {
                prop_assert_eq!(r.err(), Some(DecodeError::Malformed));
                prop_assert_eq!(d.stats().malformed, 1);
            }
        }
    }

    /// A stream of frames, some damaged: the decoder yields exactly the undamaged ones, in order,
    /// bit-exact; sequence gaps equal the lost count; every damaged (not vanished) frame is
    /// counted as bad: once, or twice when the damage created a delimiter inside it.
    #[test]
    fn damage_costs_only_the_damaged_frames(
        msgs in proptest::collection::vec(message(), 1..24),
        damages in proptest::collection::vec(proptest::option::weighted(0.3, damage()), 24),
        chunk in 1usize..64,
    ) {
        let mut stream = Vec::new();
        let mut expected = Vec::new();
        let mut damaged = 0u64;
        let mut vanished = 0u64;
        for (i, m) in msgs.iter().enumerate() {
            let p = Packet::new(i as u32, m.clone());
            let mut f = frame_of(&p);
            match &damages[i] {
                Some(d) => {
                    let before = f.clone();
                    apply(&mut f, d);
                    if f.is_empty() { vanished += 1; }
                    // A delimiter inserted next to a delimiter only adds an empty frame,
                    // which the decoder skips: the frame itself is intact.
                    else if collapse_delimiters(&f) == before { expected.push(p); } else { damaged += 1; }
                }
                None => expected.push(p),
            }
            stream.extend_from_slice(&f);
        }
        stream.push(0); // end of stream: a truncated last frame is counted too
        let mut dec = Decoder::new();
        let mut got = Vec::new();
        let mut seq = SeqTracker::new();
        for c in stream.chunks(chunk) {
            dec.feed(c, |r| if let Ok(p) = r { seq.observe(p.seq); got.push(p); });
        }
        prop_assert_eq!(got.len(), expected.len());
        for (g, e) in got.iter().zip(&expected) {
            prop_assert!(same(g, e));
        }
        // Gaps: damaged frames between the first and last good one (tail/head losses are
        // invisible to sequence numbers; the decoder's counts still see them).
        let inner_damaged = match (expected.first(), expected.last()) {
            (Some(a), Some(b)) => (a.seq..=b.seq).filter(|s| !expected.iter().any(|p| p.seq == *s)).count() as u64,
            _ => 0,
        };
        prop_assert_eq!(seq.missing, inner_damaged);
        // Gaps never exceed what was really lost (damaged or vanished).
        prop_assert!(seq.missing <= damaged + vanished);
        let bad = dec.stats().bad();
        prop_assert!(bad >= damaged && bad <= 2 * damaged, "bad {} damaged {}", bad, damaged);
        prop_assert_eq!(dec.stats().ok, expected.len() as u64);
    }

    /// Arbitrary bytes never panic and never yield a packet whose CRC did not hold.
    #[test]
    fn garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let mut dec = Decoder::new();
        let mut n = 0u64;
        dec.feed(&bytes, |_| n += 1);
        prop_assert_eq!(dec.stats().ok + dec.stats().bad(), n);
    }
}

#[test]
fn oversized_frame_is_dropped_and_next_one_survives() {
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    dec.feed(&[0x05; 2 * MAX_FRAME], |r| out.push(r));
    dec.feed(&[0], |r| out.push(r));
    let p = Packet::new(7, Message::Command(Command::Ping));
    dec.feed(&frame_of(&p), |r| out.push(r));
    assert_eq!(out.len(), 2);
    assert_eq!(out[0], Err(DecodeError::Overflow));
    assert_eq!(out[1], Ok(p));
}

#[test]
fn other_version_is_refused_and_counted() {
    let p = Packet {
        version: PROTOCOL_VERSION + 1,
        seq: 1,
        msg: Message::Command(Command::Stop),
    };
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    dec.feed(&frame_of(&p), |r| out.push(r));
    assert_eq!(out, vec![Err(DecodeError::Version(PROTOCOL_VERSION + 1))]);
    assert_eq!(dec.stats().version, 1);
}

#[test]
fn largest_message_fits() {
    let e = Estimate {
        step: u32::MAX,
        t_s: f64::MAX,
        samples: u32::MAX,
        state: [f64::MIN; 15],
        sigma: [f64::NAN; 15],
        innovation: [1.0; 3],
        nis: 2.0,
    };
    let f = frame_of(&Packet::new(u32::MAX, Message::Estimate(e)));
    assert!(f.len() <= MAX_FRAME, "{}", f.len());
    let fault = Fault::new(
        FaultCode::Panic,
        u32::MAX,
        format_args!("{}", "é".repeat(100)),
    );
    assert_eq!(fault.detail.len(), 80);
    let f = frame_of(&Packet::new(u32::MAX, Message::Fault(fault)));
    assert!(f.len() <= MAX_FRAME);
}

#[test]
fn encoder_numbers_frames() {
    let mut enc = Encoder::new();
    let mut dec = Decoder::new();
    let mut seqs = Vec::new();
    for _ in 0..3 {
        let f = enc.frame(Message::Command(Command::Ping)).unwrap().to_vec();
        dec.feed(&f, |r| seqs.push(r.unwrap().seq));
    }
    assert_eq!(seqs, vec![0, 1, 2]);
}

/// The firmware's fault details (`Detail`, no `core::fmt`): numbers as `format!` writes them,
/// and truncation to the 80 bytes of `Fault::detail` at a character boundary.
#[test]
fn details_write_numbers_and_truncate_like_format() {
    for v in [0, 7, 10, 99, 100, 65_535, 1_000_000_007, u32::MAX] {
        let mut d = Detail::new();
        d.dec(v);
        assert_eq!(d.as_str(), format!("{v}"));
        let mut d = Detail::new();
        d.hex(v, 8);
        assert_eq!(d.as_str(), format!("{v:08x}"));
    }
    for v in [0, -1, 42, i32::MIN, i32::MAX] {
        let mut d = Detail::new();
        d.signed(v);
        assert_eq!(d.as_str(), format!("{v}"));
    }
    let mut d = Detail::from("id ");
    d.hex(0xad, 2).text(" ").hex(0x1d, 2).text(" ").hex(0x5, 2);
    assert_eq!(d.as_str(), "id ad 1d 05");
    // 79 bytes, then a 2-byte character that does not fit: dropped whole; ASCII still fits.
    let mut d = Detail::from("x".repeat(79).as_str());
    d.text("é").text("yz");
    assert_eq!(d.as_str(), format!("{}y", "x".repeat(79)));
    // The same text through `Fault::new` (core::fmt) and `Fault::with_detail`.
    let mut d = Detail::from("step ");
    d.dec(39).text(": gate");
    assert_eq!(
        Fault::with_detail(FaultCode::Filter, 1, d),
        Fault::new(FaultCode::Filter, 1, format_args!("step {}: gate", 39))
    );
}

/// `MAX_PACKET` is postcard's `MaxSize` bound for the largest packet plus the CRC: an `Estimate`
/// with every varint at its longest (5 bytes for a u32) fills it exactly — the bound is neither
/// short (a packet refused) nor loose (buffers too large) — and the longest `Fault` fits.
#[test]
fn packet_size_bound_is_reached_by_the_largest_estimate() {
    let est = Estimate {
        step: u32::MAX,
        t_s: 1.0,
        samples: u32::MAX,
        state: [1.0; STATE_DIM],
        sigma: [1.0; STATE_DIM],
        innovation: [1.0; 3],
        nis: 1.0,
    };
    let largest = Packet::new(u32::MAX, Message::Estimate(est));
    let mut raw = [0u8; 2 * MAX_PACKET];
    let n = postcard::to_slice(&largest, &mut raw).unwrap().len();
    assert_eq!(n + CRC_BYTES, MAX_PACKET);
    let mut frame = [0u8; MAX_FRAME];
    assert!(encode(&largest, &mut frame).is_ok());

    let detail = Detail::from("0123456789".repeat(8).as_str());
    assert_eq!(detail.as_str().len(), 80);
    let fault = Packet::new(
        u32::MAX,
        Message::Fault(Fault::with_detail(FaultCode::Storage, u32::MAX, detail)),
    );
    let n = postcard::to_slice(&fault, &mut raw).unwrap().len();
    assert!(n + CRC_BYTES <= MAX_PACKET, "{n}");
    assert!(encode(&fault, &mut frame).is_ok());
}
