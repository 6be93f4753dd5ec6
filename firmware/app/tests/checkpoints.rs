//! Checkpoints on the host: the double-buffered store survives a power loss at any byte of a
//! write; the application resumes after a reset and ends bit-identical to an uninterrupted run;
//! a checkpoint of another model configuration or format is refused with a fault, not loaded.

use embedded_storage::nor_flash::NorFlash;
use estimator_core::Sample;
use firmware_app::app::{filter_for, App, NoTimer};
use firmware_app::checkpoints::{CheckpointStore, RamFlash, StoreError, MAX_PAYLOAD};
use firmware_app::NoSensor;
use protocol::*;

const SECTOR: usize = 4096;
type Flash<'a> = RamFlash<'a, SECTOR>;

// ---------------------------------------------------------------------------------------------
// The store

#[test]
fn store_round_trip_alternates_slots_and_keeps_the_newest() {
    let mut mem = vec![0xFFu8; 2 * SECTOR];
    let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
    let mut buf = [0u8; MAX_PAYLOAD];
    assert_eq!(
        store.load(&mut buf).unwrap(),
        None,
        "erased flash holds no checkpoint"
    );
    for g in 1..=5u32 {
        let payload: Vec<u8> = (0..(100 + g as usize * 7))
            .map(|i| (i as u32 * g) as u8)
            .collect();
        assert_eq!(store.save(&payload).unwrap(), g);
        let found = store.load(&mut buf).unwrap().unwrap();
        assert_eq!(
            (found.generation, found.slot, found.len),
            (g, ((g - 1) % 2) as usize, payload.len())
        );
        assert_eq!(&buf[..found.len], &payload[..]);
    }
}

/// A reset at any byte of a checkpoint write (the erase done, the payload or the header half
/// written) leaves the previous checkpoint loadable: never only a broken copy.
#[test]
fn a_power_loss_at_any_byte_of_a_write_keeps_the_previous_checkpoint() {
    let old: Vec<u8> = (0..300).map(|i| i as u8).collect();
    let new: Vec<u8> = (0..300).map(|i| (i as u8) ^ 0x5A).collect();
    // Bytes one save writes: the payload (rounded to 8) and the 24-byte header.
    let total = 304 + 24;
    let mut buf = [0u8; MAX_PAYLOAD];
    for cut in 0..=total {
        let mut mem = vec![0xFFu8; 2 * SECTOR];
        {
            let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
            store.load(&mut buf).unwrap();
            store.save(&old).unwrap();
            store.flash_mut().fail_after_bytes = Some(cut);
            let r = store.save(&new);
            assert_eq!(r.is_ok(), cut == total, "cut at {cut}");
        }
        // "Reset": a new store over the same memory.
        let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
        let found = store
            .load(&mut buf)
            .unwrap()
            .expect("a checkpoint survives");
        if cut == total {
            assert_eq!((found.generation, &buf[..found.len]), (2, &new[..]));
        } else {
            assert_eq!(
                (found.generation, &buf[..found.len]),
                (1, &old[..]),
                "cut at {cut}"
            );
        }
    }
}

#[test]
fn damaged_slot_is_ignored_and_other_format_is_refused() {
    let mut mem = vec![0xFFu8; 2 * SECTOR];
    let mut buf = [0u8; MAX_PAYLOAD];
    {
        let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
        store.save(&[1u8; 64]).unwrap();
        store.save(&[2u8; 64]).unwrap();
    }
    // Flip a payload bit of the newest (slot 1): the older one is loaded.
    mem[SECTOR + 24 + 10] ^= 0x01;
    {
        let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
        let f = store.load(&mut buf).unwrap().unwrap();
        assert_eq!((f.generation, buf[0]), (1, 1));
    }
    // Both slots of another record format (header CRC kept valid): refused, not loaded.
    for slot in 0..2 {
        let h = slot * SECTOR;
        mem[h + 4] = 9;
        let crc = estimator_core::checkpoint::crc32(&mem[h..h + 20]);
        mem[h + 20..h + 24].copy_from_slice(&crc.to_le_bytes());
    }
    let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
    assert_eq!(store.load(&mut buf), Err(StoreError::Format { found: 9 }));
}

// ---------------------------------------------------------------------------------------------
// The application

mod common;
use common::{HostBoard, Link};

type Fw<'a> = App<Link, NoSensor, NoTimer, HostBoard, Flash<'a>>;

fn boot(mem: &mut [u8]) -> Fw<'_> {
    let mut app = App::with_storage(
        Link::default(),
        NoSensor,
        NoTimer,
        HostBoard,
        Flash::new(mem),
    );
    app.boot();
    app
}

fn send(app: &mut Fw<'_>, enc: &mut Encoder, cmd: Command) {
    let f = enc.frame(Message::Command(cmd)).unwrap().to_vec();
    app.serial_mut().rx.extend(f);
    app.poll();
}

fn received(app: &mut Fw<'_>) -> Vec<Message> {
    let tx = std::mem::take(&mut app.serial_mut().tx);
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    dec.feed(&tx, |r| out.push(r.expect("intact").msg));
    out
}

fn input(n: usize) -> Vec<RawSample> {
    let g = 9.800898;
    let mut state = 99u64;
    (0..n)
        .map(|k| {
            let t = k as f64;
            let a = 7.29e-5 * t * 0.6;
            let mut noise = [0.0; 3];
            for v in &mut noise {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                *v = ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 1e-3;
            }
            RawSample {
                seq: k as u32,
                t_s: t,
                specific_force: [
                    g * 0.05 * a.sin() + noise[0],
                    g * 0.05 * (1.0 - a.cos()) + noise[1],
                    g + noise[2],
                ],
                temp_c: f64::NAN,
            }
        })
        .collect()
}

fn config() -> Config {
    Config {
        filter_period_s: 30.0,
        status_every: 0,
        checkpoint_every: 3,
        ..Config::default()
    }
}

fn single_pass(cfg: &Config, samples: &[RawSample]) -> Vec<Estimate> {
    let mut out = Vec::new();
    let samples = samples.iter().map(|s| Sample {
        t_s: s.t_s,
        specific_force: s.specific_force,
        temp_c: s.temp_c,
    });
    firmware_app::app::single_pass(cfg, samples, |e| out.push(e)).unwrap();
    out
}

/// Replays `samples`; resets the firmware (drops it, keeps the flash) after each sample index in
/// `resets`, with `stale` of the host's next frames lost in the reset and `in_flight` more
/// arriving at the resumed firmware before the host reacts. Returns the estimates kept by the
/// host (superseded ones dropped) and the resumes seen.
fn replay_with_resets(
    samples: &[RawSample],
    resets: &[usize],
    in_flight: usize,
) -> (Vec<Estimate>, Vec<Resume>, Counters) {
    let mut mem = vec![0xFFu8; 2 * SECTOR];
    let mut enc = Encoder::new();
    let mut estimates: Vec<Estimate> = Vec::new();
    let mut resumes = Vec::new();
    let mut app = boot(&mut mem);
    received(&mut app);
    send(&mut app, &mut enc, Command::Configure(config()));
    send(&mut app, &mut enc, Command::Start(Source::Replay));
    let mut i = 0;
    let mut pending = resets.to_vec();
    loop {
        if i < samples.len() {
            send(&mut app, &mut enc, Command::Replay(samples[i]));
            i += 1;
        } else {
            send(&mut app, &mut enc, Command::Finish);
        }
        for m in received(&mut app) {
            if let Message::Estimate(e) = m {
                estimates.push(e);
            }
        }
        if pending.first() == Some(&i) {
            pending.remove(0);
            drop(app);
            app = boot(&mut mem);
            let boot_msgs = received(&mut app);
            let st = boot_msgs
                .iter()
                .find_map(|m| {
                    if let Message::Status(s) = m {
                        Some(*s)
                    } else {
                        None
                    }
                })
                .unwrap();
            assert!(st.boot);
            let r = st
                .resumed
                .expect("a checkpoint exists after the first three updates");
            resumes.push(r);
            // Frames already on the wire reach the resumed firmware first (discarded), then
            // the host resends from the checkpoint's sample.
            for s in samples.iter().skip(i).take(in_flight) {
                send(&mut app, &mut enc, Command::Replay(*s));
            }
            if i + in_flight >= samples.len() {
                send(&mut app, &mut enc, Command::Finish);
            }
            estimates.retain(|e| e.step < r.step);
            i = r.next_seq as usize;
            continue;
        }
        if i == samples.len() && !app.status().running {
            break;
        }
    }
    for m in received(&mut app) {
        if let Message::Estimate(e) = m {
            estimates.push(e);
        }
    }
    let c = *app.counters();
    (estimates, resumes, c)
}

#[test]
fn resets_at_many_points_end_bit_identical_to_an_uninterrupted_run() {
    let samples = input(1500);
    let want = single_pass(&config(), &samples);
    assert_eq!(want.len(), 50);
    // Resets right after a checkpoint, in the middle of windows, twice in a row, near the end.
    let resets = [95, 181, 182, 600, 777, 1001, 1490];
    let (got, resumes, c) = replay_with_resets(&samples, &resets, 40);
    assert_eq!(resumes.len(), resets.len());
    for (r, &at) in resumes.iter().zip(&resets) {
        // The checkpoint is at most `checkpoint_every` updates (3 × 30 s) behind the reset.
        assert!(
            r.next_seq as usize <= at && at - r.next_seq as usize <= 3 * 30 + 30,
            "reset at {at}: {r:?}"
        );
    }
    // Bit-identical: the checkpoint restores the filter exactly (f64 bytes) at a window boundary
    // and the resent samples are the same, so nothing differs from the uninterrupted run.
    assert_eq!(got.len(), want.len());
    assert_eq!(got, want);
    // Counters restart at boot: after the last reset (at 1490) the 10 samples still in flight
    // and the early Finish were discarded while waiting for the checkpoint's sample.
    assert_eq!(c.samples_resync, 10 + 1);
}

#[test]
fn a_finished_run_is_not_resumed() {
    let samples = input(200);
    let mut mem = vec![0xFFu8; 2 * SECTOR];
    let mut enc = Encoder::new();
    {
        let mut app = boot(&mut mem);
        send(&mut app, &mut enc, Command::Configure(config()));
        send(&mut app, &mut enc, Command::Start(Source::Replay));
        for s in &samples {
            send(&mut app, &mut enc, Command::Replay(*s));
        }
        assert!(app.counters().checkpoints_written >= 2);
        send(&mut app, &mut enc, Command::Finish);
    }
    let mut app = boot(&mut mem);
    let st = received(&mut app)
        .iter()
        .find_map(|m| {
            if let Message::Status(s) = m {
                Some(*s)
            } else {
                None
            }
        })
        .unwrap();
    assert_eq!((st.boot, st.running, st.resumed), (true, false, None));
}

/// A checkpoint whose filter image was written for another model configuration (here: another
/// gyro noise, as a firmware with a different model would) is refused with a fault naming why.
#[test]
fn a_checkpoint_of_another_model_configuration_is_refused() {
    let mut mem = vec![0xFFu8; 2 * SECTOR];
    let cfg = config();
    let other = Config {
        arw_deg2_per_h: 4e-8,
        ..cfg
    };
    let ekf = filter_for(&other).unwrap();
    // The application's payload: resume block v1 (source, next sample, last time, config) and
    // the core's image — see `App::restore`.
    let mut payload = vec![0u8; 20];
    payload[0..2].copy_from_slice(&1u16.to_le_bytes());
    payload[2] = 1;
    payload[8..16].copy_from_slice(&f64::NAN.to_le_bytes());
    let cfg_bytes = postcard::to_allocvec(&cfg).unwrap();
    payload[16..18].copy_from_slice(&(cfg_bytes.len() as u16).to_le_bytes());
    payload.extend(cfg_bytes);
    let mut image = vec![0u8; estimator_core::checkpoint::size(15)];
    ekf.checkpoint(&mut image).unwrap();
    payload.extend(image);
    {
        let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
        store.save(&payload).unwrap();
    }
    let mut app = boot(&mut mem);
    let msgs = received(&mut app);
    let st = msgs
        .iter()
        .find_map(|m| {
            if let Message::Status(s) = m {
                Some(*s)
            } else {
                None
            }
        })
        .unwrap();
    assert_eq!((st.running, st.resumed), (false, None), "not loaded");
    let fault = msgs
        .iter()
        .find_map(|m| {
            if let Message::Fault(f) = m {
                Some(f.clone())
            } else {
                None
            }
        })
        .expect("a fault");
    assert_eq!(fault.code, FaultCode::CheckpointRefused);
    assert!(
        fault.detail.contains("another model configuration"),
        "{}",
        fault.detail
    );
    // Sanity: the same payload with the right image is accepted.
    let good = filter_for(&cfg).unwrap();
    let n = payload.len() - estimator_core::checkpoint::size(15);
    good.checkpoint(&mut payload[n..]).unwrap();
    drop(app);
    {
        let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
        let mut buf = [0u8; MAX_PAYLOAD];
        store.load(&mut buf).unwrap();
        store.save(&payload).unwrap();
    }
    let mut app = boot(&mut mem);
    let st = received(&mut app)
        .iter()
        .find_map(|m| {
            if let Message::Status(s) = m {
                Some(*s)
            } else {
                None
            }
        })
        .unwrap();
    assert!(st.running && st.resumed.is_some());
    let _ = <Flash<'_> as NorFlash>::ERASE_SIZE;
}
