//! The application loop on the host, over an in-memory link: replay gives the core's single-pass
//! estimates bit for bit; bad samples and bad frames are rejected and counted; commands in the
//! wrong state are refused; sensor mode samples at the timer's ticks.

use estimator_core::screening::ScreenConfig;
use estimator_core::{Averager, Sample};
use firmware_app::app::{filter_for, App, Event, NoTimer, SampleTimer, Tick};
use firmware_app::{AccelSample, Accelerometer, NoSensor};
use protocol::*;

mod common;
use common::{HostBoard, Link};

struct Host {
    enc: Encoder,
    dec: Decoder,
}

impl Host {
    fn new() -> Self {
        Host {
            enc: Encoder::new(),
            dec: Decoder::new(),
        }
    }
    fn send<A: Accelerometer, T: SampleTimer>(
        &mut self,
        app: &mut App<Link, A, T, HostBoard>,
        cmd: Command,
    ) -> Event {
        let f = self.enc.frame(Message::Command(cmd)).unwrap().to_vec();
        app.serial_mut().rx.extend(f);
        app.poll()
    }
    fn receive<A: Accelerometer, T: SampleTimer>(
        &mut self,
        app: &mut App<Link, A, T, HostBoard>,
    ) -> Vec<Message> {
        let tx = std::mem::take(&mut app.serial_mut().tx);
        let mut out = Vec::new();
        self.dec.feed(&tx, |r| {
            out.push(r.expect("firmware frames are intact").msg)
        });
        out
    }
}

fn samples(n: usize) -> Vec<Sample> {
    // Gravity on a slowly turning platform, with a deterministic pseudo-noise.
    let g = 9.800898;
    let mut state = 12345u64;
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
            Sample {
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

fn replay_sample(k: u32, s: &Sample) -> Command {
    Command::Replay(RawSample {
        seq: k,
        t_s: s.t_s,
        specific_force: s.specific_force,
        temp_c: s.temp_c,
    })
}

#[test]
fn replay_matches_the_core_single_pass_bit_for_bit_and_rejects_bad_samples() {
    let mut app = App::new(Link::default(), NoSensor, NoTimer, HostBoard);
    app.boot();
    let mut host = Host::new();
    let hello = host.receive(&mut app);
    assert!(matches!(
        hello[0],
        Message::Hello(Hello {
            board: Board::Host,
            state_dim: 15,
            ..
        })
    ));
    let config = Config {
        filter_period_s: 30.0,
        status_every: 0,
        ..Config::default()
    };
    host.send(&mut app, Command::Configure(config));
    host.send(&mut app, Command::Start(Source::Replay));
    let input = samples(1000);
    for (k, s) in input.iter().enumerate() {
        host.send(&mut app, replay_sample(k as u32, s));
        if k == 500 {
            // Bad samples in between: NaN, saturated, duplicate time, out of order.
            let mut bad = *s;
            bad.t_s += 0.5;
            bad.specific_force[1] = f64::NAN;
            host.send(&mut app, replay_sample(9000, &bad));
            bad.specific_force[1] = 30.0;
            host.send(&mut app, replay_sample(9001, &bad));
            host.send(&mut app, replay_sample(9002, s));
            bad.t_s -= 3.0;
            bad.specific_force[1] = 0.0;
            host.send(&mut app, replay_sample(9003, &bad));
        }
    }
    host.send(&mut app, Command::Finish);
    let got: Vec<Estimate> = host
        .receive(&mut app)
        .into_iter()
        .filter_map(|m| {
            if let Message::Estimate(e) = m {
                Some(e)
            } else {
                None
            }
        })
        .collect();

    // The host's single pass on the same (good) samples.
    let mut ekf = filter_for(&config).unwrap();
    let mut avg = Averager::new(config.filter_period_s, config.raw_sigma_mps2);
    let mut want = Vec::new();
    let mut ms: Vec<_> = input.iter().filter_map(|s| avg.push(s)).collect();
    ms.extend(avg.flush());
    for m in ms {
        let step = ekf.steps();
        let r = ekf.step(&m).unwrap();
        want.push(firmware_app::app::estimate_of(
            &ekf,
            step,
            &m,
            r.innovation,
            r.nis,
        ));
    }
    assert_eq!(got.len(), 34);
    assert_eq!(got, want);
    let c = app.counters();
    assert_eq!(
        (
            c.samples_ok,
            c.samples_nan,
            c.samples_saturated,
            c.samples_duplicate,
            c.samples_out_of_order
        ),
        (1000, 1, 1, 1, 1)
    );
    assert_eq!(
        (
            c.filter_steps,
            c.filter_errors,
            c.frames_rx_bad,
            c.frames_rx_missing
        ),
        (34, 0, 0, 0)
    );
    assert!(!app.status().running);
}

#[test]
fn damaged_and_missing_frames_are_counted() {
    let mut app = App::new(Link::default(), NoSensor, NoTimer, HostBoard);
    let mut host = Host::new();
    host.send(&mut app, Command::Start(Source::Replay));
    let mut f = host
        .enc
        .frame(Message::Command(Command::Ping))
        .unwrap()
        .to_vec();
    f[3] ^= 0x40;
    app.serial_mut().rx.extend(f);
    let _lost = host.enc.frame(Message::Command(Command::Ping)).unwrap();
    app.poll();
    host.send(&mut app, Command::Ping);
    let c = app.counters();
    assert_eq!(
        (c.frames_rx, c.frames_rx_bad, c.frames_rx_missing),
        (2, 1, 2)
    );
}

#[test]
fn commands_in_the_wrong_state_are_refused() {
    let mut app = App::new(Link::default(), NoSensor, NoTimer, HostBoard);
    let mut host = Host::new();
    host.send(&mut app, replay_sample(0, &samples(1)[0]));
    host.send(&mut app, Command::Start(Source::Sensor)); // no sensor on this board
    let bad = Config {
        latitude_deg: 95.0,
        ..Config::default()
    };
    host.send(&mut app, Command::Configure(bad));
    host.send(&mut app, Command::Start(Source::Replay));
    host.send(&mut app, Command::Configure(Config::default())); // while running
    let faults: Vec<FaultCode> = host
        .receive(&mut app)
        .into_iter()
        .filter_map(|m| {
            if let Message::Fault(f) = m {
                Some(f.code)
            } else {
                None
            }
        })
        .collect();
    assert_eq!(
        faults,
        vec![
            FaultCode::BadCommand,
            FaultCode::BadCommand,
            FaultCode::BadConfig,
            FaultCode::BadCommand
        ]
    );
    assert_eq!(app.counters().commands_refused, 4);
    assert_eq!(host.send(&mut app, Command::Shutdown), Event::Shutdown);
}

struct FakeTimer {
    next: u32,
    running: bool,
}
impl SampleTimer for FakeTimer {
    fn start(&mut self, _rate_hz: f64) {
        self.running = true;
        self.next = 0;
    }
    fn stop(&mut self) {
        self.running = false;
    }
    fn poll(&mut self) -> Option<Tick> {
        if !self.running {
            return None;
        }
        let i = self.next;
        // Tick 5 is missed (the loop was late); ticks go on at 6.
        let missed = u32::from(i == 5);
        self.next += 1 + missed;
        Some(Tick {
            index: i + missed,
            missed,
        })
    }
}

struct FakeAccel {
    reads: u32,
    /// From this read on, the converter is frozen: every axis repeats this read's values.
    stuck_from: u32,
}
impl Accelerometer for FakeAccel {
    type Error = ();
    fn sample(&mut self, t_s: f64) -> Result<AccelSample, ()> {
        self.reads += 1;
        // A live sensor's readings differ from sample to sample (noise).
        let x = 1e-6 * f64::from(self.reads.min(self.stuck_from));
        match self.reads {
            3 => Err(()),
            4 => Ok(AccelSample {
                t_s,
                specific_force: [x, -x, 9.8 + x],
                temp_c: 20.0,
                saturated: true,
            }),
            _ => Ok(AccelSample {
                t_s,
                specific_force: [x, -x, 9.8 + x],
                temp_c: 20.0,
                saturated: false,
            }),
        }
    }
}

#[test]
fn sensor_mode_samples_at_the_ticks_and_counts_read_errors() {
    let mut app = App::new(
        Link::default(),
        FakeAccel {
            reads: 0,
            stuck_from: u32::MAX,
        },
        FakeTimer {
            next: 0,
            running: false,
        },
        HostBoard,
    );
    let mut host = Host::new();
    host.send(
        &mut app,
        Command::Configure(Config {
            filter_period_s: 4.0,
            ..Config::default()
        }),
    );
    host.send(&mut app, Command::Start(Source::Sensor));
    for _ in 0..20 {
        app.poll();
    }
    // The end of the run: the samples the screening still holds come out and are counted.
    host.send(&mut app, Command::Finish);
    let msgs = host.receive(&mut app);
    let raws: Vec<f64> = msgs
        .iter()
        .filter_map(|m| {
            if let Message::Raw(r) = m {
                Some(r.t_s)
            } else {
                None
            }
        })
        .collect();
    // 21 reads (the poll that started the run takes tick 0) at ticks 0,1,2,3,4,6,7,...:
    // read 3 (t=2) failed, read 4 (t=3) saturated, tick 5 missed.
    assert_eq!(raws[..4], [0.0, 1.0, 4.0, 6.0]);
    let c = app.counters();
    assert_eq!(
        (c.samples_ok, c.read_errors, c.samples_saturated),
        (19, 2, 1)
    );
    assert!(msgs.iter().any(|m| matches!(m, Message::Estimate(_))));
}

/// A stuck sensor (the same reading over and over) is rejected and counted by the core's
/// screening: a run of identical readings is recognised once it is longer than the noise allows
/// (`ScreenConfig::min_stuck_run` = 5 readings for a sensor that never repeated a reading before),
/// while all of it is still held by the screening, so the whole run is rejected.
#[test]
fn a_stuck_sensor_is_rejected_and_counted() {
    let mut app = App::new(
        Link::default(),
        FakeAccel {
            reads: 0,
            stuck_from: 11,
        },
        FakeTimer {
            next: 0,
            running: false,
        },
        HostBoard,
    );
    let mut host = Host::new();
    host.send(
        &mut app,
        Command::Configure(Config {
            filter_period_s: 4.0,
            ..Config::default()
        }),
    );
    host.send(&mut app, Command::Start(Source::Sensor));
    for _ in 0..30 {
        app.poll();
    }
    host.send(&mut app, Command::Finish);
    let c = *app.counters();
    // Reads 11..=31 are stuck (31 reads: the start poll + 30), all 21 rejected. Reads 3 (error)
    // and 4 (saturated) as in the test above.
    assert_eq!(ScreenConfig::default().min_stuck_run, 5);
    assert_eq!(c.samples_stuck, 21);
    // 31 reads: 1 failed, 1 saturated, 21 stuck, the rest good (read_errors also counts the
    // missed tick 5, which is not a read).
    assert_eq!(c.samples_ok, 31 - 1 - 1 - 21, "{c:?}");
    assert_eq!((c.samples_glitch, c.samples_dropout), (0, 0));
    assert_eq!(c.read_errors, 2);
    let _ = host.receive(&mut app);
}

/// A glitch and a stuck run in a replayed recording are rejected by the firmware's path (the
/// core's screening) and nothing else is: the estimates are bit for bit the single pass over
/// the recording without those samples, the counters name them, and they would have changed
/// the estimates had they been averaged.
#[test]
fn a_glitch_and_a_stuck_run_are_rejected_and_nothing_else() {
    let config = Config {
        filter_period_s: 30.0,
        status_every: 0,
        ..Config::default()
    };
    let clean = samples(1200);
    let mut input = clean.clone();
    // A glitch: +0.05 m/s² on x for one sample (66σ of the configured raw noise 7.6e-4).
    input[300].specific_force[0] += 0.05;
    // y stuck at one reading for 40 samples (its first reading is sample 700's own).
    for k in 700..740 {
        input[k].specific_force[1] = input[700].specific_force[1];
    }
    let rejected = |k: usize| k == 300 || (700..740).contains(&k);

    let mut app = App::new(Link::default(), NoSensor, NoTimer, HostBoard);
    let mut host = Host::new();
    host.send(&mut app, Command::Configure(config));
    host.send(&mut app, Command::Start(Source::Replay));
    for (k, s) in input.iter().enumerate() {
        host.send(&mut app, replay_sample(k as u32, s));
    }
    host.send(&mut app, Command::Finish);
    let got: Vec<Estimate> = host
        .receive(&mut app)
        .into_iter()
        .filter_map(|m| match m {
            Message::Estimate(e) => Some(e),
            _ => None,
        })
        .collect();
    let c = *app.counters();
    assert_eq!(
        (
            c.samples_glitch,
            c.samples_stuck,
            c.samples_dropout,
            c.samples_ok
        ),
        (1, 40, 0, 1200 - 41),
        "{c:?}"
    );

    let single = |samples: Vec<Sample>| {
        let mut out = Vec::new();
        let counts = firmware_app::app::single_pass(&config, samples, |e| out.push(e)).unwrap();
        (out, counts)
    };
    // The host's reference on the same input counts the same rejections.
    let (want, counts) = single(input.clone());
    assert_eq!(got, want);
    assert_eq!(
        (
            counts.samples_glitch,
            counts.samples_stuck,
            counts.samples_ok
        ),
        (1, 40, 1200 - 41)
    );
    // The recording without the faulty samples gives the same estimates: the screening removed
    // exactly those.
    let kept: Vec<Sample> = (0..input.len())
        .filter(|&k| !rejected(k))
        .map(|k| input[k])
        .collect();
    let (without, counts) = single(kept);
    assert_eq!(counts.samples_ok, 1200 - 41);
    assert_eq!(got, without);
    // Averaged, they would have moved the estimates.
    let mut ekf = filter_for(&config).unwrap();
    let mut avg = Averager::new(config.filter_period_s, config.raw_sigma_mps2);
    let mut ms: Vec<_> = input.iter().filter_map(|s| avg.push(s)).collect();
    ms.extend(avg.flush());
    let mut unscreened = Vec::new();
    for m in ms {
        let step = ekf.steps();
        let r = ekf.step(&m).unwrap();
        unscreened.push(firmware_app::app::estimate_of(
            &ekf,
            step,
            &m,
            r.innovation,
            r.nis,
        ));
    }
    assert_ne!(got, unscreened);
}

/// With the χ² gate on, a window of bad samples (a 0.05 m/s² shock on every axis, ~100σ of a
/// 30-s mean) is rejected and counted — its estimate still goes out, flagged by its NIS — and a
/// long run of them raises a filter fault instead of starving the filter.
#[test]
fn the_innovation_gate_rejects_counts_and_faults_on_a_run() {
    let mut app = App::new(Link::default(), NoSensor, NoTimer, HostBoard);
    let mut host = Host::new();
    let config = Config {
        filter_period_s: 30.0,
        status_every: 0,
        gate_nis: 27.88,
        ..Config::default()
    };
    host.send(&mut app, Command::Configure(config));
    host.send(&mut app, Command::Start(Source::Replay));
    let input = samples(30 * 60);
    let shocked = |k: usize| (600..630).contains(&k) || k >= 900;
    for (k, s) in input.iter().enumerate() {
        let mut s = *s;
        if shocked(k) {
            for a in &mut s.specific_force {
                *a += 0.05;
            }
        }
        host.send(&mut app, replay_sample(k as u32, &s));
    }
    let msgs = host.receive(&mut app);
    let c = *app.counters();
    // Window 20 (samples 600..630) rejected once; from sample 900 on every window is bad: the
    // 10th rejection in a row (windows 30..=39) is refused as a fault, and so is each after it.
    assert!(c.updates_rejected >= 10, "{c:?}");
    let faults: Vec<_> = msgs
        .iter()
        .filter_map(|m| {
            if let Message::Fault(f) = m {
                Some(f.clone())
            } else {
                None
            }
        })
        .collect();
    assert!(
        !faults.is_empty() && faults.iter().all(|f| f.code == FaultCode::Filter),
        "{faults:?}"
    );
    assert!(
        faults[0].detail.contains("step 39") && faults[0].detail.contains("innovation gate"),
        "{}",
        faults[0].detail
    );
    // Before the shocks nothing was rejected: the gate does not bite on good data.
    let nis: Vec<f64> = msgs
        .iter()
        .filter_map(|m| {
            if let Message::Estimate(e) = m {
                Some(e.nis)
            } else {
                None
            }
        })
        .collect();
    assert!(nis[..19].iter().all(|&v| v < 27.88), "{:?}", &nis[..19]);
    assert!(nis[20] > 27.88);
}
