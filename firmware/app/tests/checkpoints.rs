//! Checkpoints on the host: the append-only checkpoint log survives a power loss at any byte of
//! a write or an erase and erases a sector once per sector-full of checkpoints; the application
//! resumes after a reset and ends bit-identical to an uninterrupted run; a checkpoint of another
//! model configuration or format is refused with a fault, not loaded.

use embedded_storage::nor_flash::NorFlash;
use estimator_core::Sample;
use firmware_app::app::{filter_for, App, NoTimer};
use firmware_app::checkpoints::{CheckpointStore, RamFlash, StoreError, HEADER, MAX_PAYLOAD};
use firmware_app::NoSensor;
use protocol::*;

const SECTOR: usize = 4096;
type Flash<'a> = RamFlash<'a, SECTOR>;

// ---------------------------------------------------------------------------------------------
// The store

fn payload(g: u32, len: usize) -> Vec<u8> {
    (0..len).map(|i| (i as u32 * 31 + g * 7) as u8).collect()
}

#[test]
fn store_appends_records_and_keeps_the_newest() {
    let mut mem = vec![0xFFu8; 2 * SECTOR];
    let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
    let mut buf = [0u8; MAX_PAYLOAD];
    assert_eq!(
        store.load(&mut buf).unwrap(),
        None,
        "erased flash holds no checkpoint"
    );
    // 300-byte payloads: records of 24 + 304 = 328 bytes (8-byte writes), 12 per 4-KiB sector.
    assert_eq!(CheckpointStore::<Flash<'_>>::records_per_sector(300), 12);
    for g in 1..=30u32 {
        let p = payload(g, 300);
        assert_eq!(store.save(&p).unwrap(), g);
        let found = store.load(&mut buf).unwrap().unwrap();
        // Records fill sector 0, then sector 1, then sector 0 again (erased) ...
        let k = (g - 1) as usize;
        assert_eq!(
            (found.generation, found.sector, found.offset, found.len),
            (g, (k / 12) % 2, (k % 12) as u32 * 328, 300)
        );
        assert_eq!(&buf[..found.len], &p[..]);
    }
    // 30 records, 12 per sector: each move to the next sector erases it first (sector 1 for
    // records 13.., sector 0 for 25..): 2 erases.
    assert_eq!(store.flash_mut().erases, 2);
}

/// Saves `n` 300-byte records (generations 1..=n) on fresh flash.
fn filled(mem: &mut [u8], n: u32) {
    let mut store = CheckpointStore::new(Flash::new(mem)).unwrap();
    for g in 1..=n {
        store.save(&payload(g, 300)).unwrap();
    }
}

/// A reset at any byte of a checkpoint save — a plain append, or one that first erases the next
/// sector (at every byte of the erase, then of the write) — leaves the previous checkpoint
/// loadable, and the store goes on appending afterwards: never only a broken copy.
#[test]
fn a_power_loss_at_any_byte_of_a_write_or_erase_keeps_the_previous_checkpoint() {
    let mut buf = [0u8; MAX_PAYLOAD];
    // Before: 5 records (an append into sector 0), 12 (sector 0 full: the save erases sector 1),
    // 24 (both full: the save erases sector 0, which holds the oldest records).
    for before in [5u32, 12, 24] {
        let rollover = before % 12 == 0;
        // Bytes one save writes: the payload (304) and the header (24), plus the erased sector.
        let total = 304 + 24 + if rollover { SECTOR } else { 0 };
        let mut mem0 = vec![0xFFu8; 2 * SECTOR];
        filled(&mut mem0, before);
        for cut in 0..=total {
            let mut mem = mem0.clone();
            {
                let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
                store.load(&mut buf).unwrap();
                store.flash_mut().fail_after_bytes = Some(cut);
                let r = store.save(&payload(before + 1, 300));
                assert_eq!(r.is_ok(), cut == total, "before {before}, cut at {cut}");
            }
            // "Reset": a new store over the same memory.
            let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
            let found = store
                .load(&mut buf)
                .unwrap()
                .expect("a checkpoint survives");
            let want = if cut == total { before + 1 } else { before };
            assert_eq!(
                (found.generation, &buf[..found.len]),
                (want, &payload(want, 300)[..]),
                "before {before}, cut at {cut}"
            );
            // The log goes on: the next save is the newest (and nothing is programmed twice:
            // RamFlash refuses to write a byte that is not erased).
            assert_eq!(store.save(&payload(want + 1, 300)).unwrap(), want + 1);
            let found = store.load(&mut buf).unwrap().unwrap();
            assert_eq!(
                (found.generation, &buf[..found.len]),
                (want + 1, &payload(want + 1, 300)[..]),
                "before {before}, cut at {cut}: the save after the reset"
            );
        }
    }
}

#[test]
fn damaged_record_is_ignored_and_other_format_is_refused() {
    let mut mem = vec![0xFFu8; 2 * SECTOR];
    let mut buf = [0u8; MAX_PAYLOAD];
    {
        let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
        store.save(&[1u8; 64]).unwrap();
        store.save(&[2u8; 64]).unwrap();
    }
    // Records of 24 + 64 = 88 bytes. Flip a payload bit of the newest: the older one is loaded.
    mem[88 + HEADER + 10] ^= 0x01;
    {
        let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
        let f = store.load(&mut buf).unwrap().unwrap();
        assert_eq!((f.generation, buf[0]), (1, 1));
    }
    // Records of another format only (header CRC kept valid): refused, not loaded.
    for h in [0, 88] {
        mem[h + 4] = 9;
        let crc = estimator_core::checkpoint::crc32(&mem[h..h + 20]);
        mem[h + 20..h + 24].copy_from_slice(&crc.to_le_bytes());
    }
    let mut store = CheckpointStore::new(Flash::new(&mut mem)).unwrap();
    assert_eq!(store.load(&mut buf), Err(StoreError::Format { found: 9 }));
}

/// Every configuration's checkpoint payload fits the store's (deliberately tight) buffer: the
/// longest postcard encoding has gravity set and the varint counters at their maximum.
#[test]
fn the_longest_configuration_fits_max_payload() {
    let longest = Config {
        gravity_mps2: Some(9.8),
        status_every: u32::MAX,
        checkpoint_every: u32::MAX,
        ..Config::default()
    };
    let default = firmware_app::resume::payload_len(&Config::default()).unwrap();
    let max = firmware_app::resume::payload_len(&longest).unwrap();
    // Default: 20 + 137 + 640 (screening state: 2 × 7 held samples) + 1 068; longest: +8
    // (gravity) +4 (status_every: 5 varint bytes, not 1) +4 (checkpoint_every: 5, not 1).
    assert_eq!((default, max), (1865, 1881));
    assert!(max <= MAX_PAYLOAD);
}

/// Flash wear on the STM32H743's geometry (two 128-KiB sectors, 32-byte flash words) with the
/// application's real checkpoint payload: erases are counted over many checkpoints and turned
/// into erases per day and flash life at the default settings.
#[test]
fn flash_wear_at_the_default_settings_lasts_over_ten_years() {
    const H7_SECTOR: usize = 128 * 1024;
    type H7Flash<'a> = RamFlash<'a, H7_SECTOR, 32>;
    let cfg = Config::default();
    // The payload the application writes: resume block + the core's 15-state image.
    let len = firmware_app::resume::payload_len(&cfg).expect("default config encodes");
    let per_sector = CheckpointStore::<H7Flash<'_>>::records_per_sector(len);
    // 1 865-byte payload -> 32 + 1 888 = 1 920-byte records, 68 per sector.
    assert_eq!((len, per_sector), (1865, 68), "payload and records/sector");
    let mut mem = vec![0xFFu8; 2 * H7_SECTOR];
    let mut store = CheckpointStore::new(H7Flash::new(&mut mem)).unwrap();
    let p = payload(0, len);
    let n = 10 * per_sector as u64 + 1;
    for _ in 0..n {
        store.save(&p).unwrap();
    }
    let erases = store.flash_mut().erases;
    // The log starts in sector 0 without an erase; each move to the next sector erases it
    // first: 10 moves for 10 sector-fulls + 1 record.
    assert_eq!(erases, 10, "erases for {n} checkpoints");
    // Default: a checkpoint every 10 updates of 60 s = 144 a day.
    assert_eq!((cfg.checkpoint_every, cfg.filter_period_s), (10, 60.0));
    let per_day = 86_400.0 / (cfg.checkpoint_every as f64 * cfg.filter_period_s);
    let erases_per_day = per_day * erases as f64 / n as f64;
    // Two sectors share the erases; each is rated for 10 000 cycles.
    let life_years = 10_000.0 * 2.0 / erases_per_day / 365.25;
    println!(
        "flash wear: {len}-byte payload, {per_sector} records/sector, {erases} erases for {n} checkpoints; {erases_per_day:.2} erases/day; life {life_years:.1} years at 10 000 cycles"
    );
    // 144 / 68 = 2.12 erases/day (the extra 681st record makes it 2.12 x 680/681): 25.9
    // years; 0.02 covers that rounding. The floor is 10 years; the old two-slot store (an
    // erase per checkpoint, 144/day) gave 0.38 years.
    assert!((erases_per_day - 2.12).abs() < 0.02, "{erases_per_day}");
    assert!(life_years >= 10.0, "{life_years}");
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
    // (The first checkpoint follows update 3, when sample 90 opens window 3: it comes out of
    // the screening, and is averaged, when sample 97 arrives.)
    let resets = [98, 181, 182, 600, 777, 1001, 1490];
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
    // The application's payload (`firmware_app::resume`): this run's configuration, the other
    // model's filter image.
    let point = firmware_app::resume::ResumePoint {
        next_seq: 0,
        last_t_s: None,
    };
    let mut buf = [0u8; MAX_PAYLOAD];
    let screen = firmware_app::screen::Screen::new(&cfg, None);
    let n = firmware_app::resume::encode_run(&mut buf, Source::Replay, point, &cfg, &screen, &ekf)
        .unwrap();
    let mut payload = buf[..n].to_vec();
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

/// A reset after every sample across two checkpoints, with a glitch and a dropout for the
/// screening to reject near them: the screening hands samples out `half_window` samples late,
/// so a checkpoint's sample index, the screening state it holds and the averaging window it
/// reopens must agree wherever the reset lands (each resumed run ends bit-identical to the
/// uninterrupted one, the rejections counted the same).
#[test]
fn a_reset_after_any_sample_resumes_the_screened_run_exactly() {
    let mut samples = input(400);
    samples[150].specific_force[0] += 0.05; // a glitch
    samples[183].specific_force = [0.0; 3]; // a dropout, just before the checkpoint at 187
    let cfg = config();
    let mut want = Vec::new();
    let want_counts = firmware_app::app::single_pass(
        &cfg,
        samples.iter().map(|s| Sample {
            t_s: s.t_s,
            specific_force: s.specific_force,
            temp_c: s.temp_c,
        }),
        |e| want.push(e),
    )
    .unwrap();
    assert_eq!(
        (want_counts.samples_glitch, want_counts.samples_dropout),
        (1, 1)
    );
    // The first checkpoint follows update 3 (sample 97 in); the next one update 6 (187).
    for at in 98..=200 {
        let (got, resumes, _) = replay_with_resets(&samples, &[at], 7);
        assert_eq!(resumes.len(), 1);
        assert_eq!(
            got, want,
            "reset after sample {at}: resumed {:?}",
            resumes[0]
        );
    }
}
