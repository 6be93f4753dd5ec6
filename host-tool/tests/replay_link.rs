//! `replay` against fake firmwares on a pseudo-terminal (issue 28, item 3): a fake firmware
//! thread reads the host's commands on the pty's slave side and answers with frames built by the
//! protocol crate. A well-behaved one gives every estimate; one that reports faults, says "done"
//! early, resumes past the end, sends an estimate it could not compute or stops answering makes
//! the replay fail, naming what happened.

#![cfg(unix)]

use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use host_tool::link::port::{pty_pair, writer_of, POLL};
use host_tool::link::replay::{self, ReplayOptions, ReplayOutcome};
use host_tool::link::Receiver;
use protocol::{
    Board, Command, Config, Counters, Encoder, Estimate, Fault, FaultCode, Hello, Message,
    RawSample, Resume, Source, Status, STATE_DIM,
};
use serialport::SerialPort as _;

/// Filter period of the fake firmware and of the host, s.
const PERIOD_S: f64 = 60.0;
/// Samples replayed: 600 at 1 Hz, ten filter periods.
const SAMPLES: u32 = 600;

/// How the fake firmware misbehaves.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Script {
    Good,
    /// A fault at Finish, and no estimate ever.
    FaultsThenDone,
    /// One estimate only, then "done" at Finish.
    DoneEarly,
    /// Every estimate but step 3's (its steps numbered on).
    SkipsStep,
    /// Reboots after sample 5 and resumes from a checkpoint at sample 10 000.
    ResumePastEnd,
    /// The second estimate's D(X)_0 is NaN.
    NanEstimate,
    /// The first estimate's NIS is infinite.
    InfiniteNis,
    /// The first estimate's time is NaN.
    NanTime,
    /// Answers Start, then never sends again (it goes on reading).
    Silent,
    /// Every estimate, and a filter fault at step 2.
    FaultMidRun,
}

fn status(running: bool, boot: bool, resumed: Option<Resume>, frames_rx: u32) -> Message {
    Message::Status(Status {
        t_s: 0.0,
        running,
        source: Source::Replay,
        counters: Counters {
            frames_rx,
            ..Counters::default()
        },
        stack_used_bytes: 0,
        stack_size_bytes: 0,
        static_ram_bytes: 0,
        last_step_ticks: 0,
        tick_hz: 0,
        boot,
        resumed,
    })
}

fn estimate(step: u32, t_s: f64) -> Estimate {
    Estimate {
        step,
        t_s,
        samples: 60,
        state: [0.0; STATE_DIM],
        sigma: [1e-3; STATE_DIM],
        innovation: [0.0; 3],
        nis: 3.0,
    }
}

/// The fake firmware's sending side.
struct Tx {
    port: serialport::TTYPort,
    enc: Encoder,
    script: Script,
    steps: u32,
}

impl Tx {
    fn send(&mut self, m: Message) {
        let f = self.enc.frame(m).unwrap().to_vec();
        let _ = self.port.write_all(&f);
    }

    /// Ends the window of sample times `window` with an estimate (the script may spoil it).
    fn step(&mut self, window: &mut Vec<f64>) {
        let t = window.iter().sum::<f64>() / window.len() as f64;
        let mut e = estimate(self.steps, t);
        match (self.script, self.steps) {
            (Script::NanEstimate, 1) => e.state[3] = f64::NAN,
            (Script::InfiniteNis, 0) => e.nis = f64::INFINITY,
            (Script::NanTime, 0) => e.t_s = f64::NAN,
            _ => {}
        }
        let skip = match self.script {
            Script::DoneEarly => self.steps > 0,
            Script::SkipsStep => self.steps == 3,
            _ => false,
        };
        if !skip {
            self.send(Message::Estimate(e));
        }
        if self.script == Script::FaultMidRun && self.steps == 2 {
            let f = Fault::new(FaultCode::Filter, 2, format_args!("update refused"));
            self.send(Message::Fault(f));
        }
        self.steps += 1;
        window.clear();
    }
}

/// The fake firmware: answers the host's commands on `port` by `script` until `done`.
fn fake_firmware(port: serialport::TTYPort, script: Script, done: Arc<AtomicBool>) {
    let mut port_rx = port.try_clone_native().unwrap();
    let mut tx = Tx {
        port,
        enc: Encoder::new(),
        script,
        steps: 0,
    };
    let mut rx = Receiver::new();
    let (mut window, mut frames, mut silent) = (Vec::<f64>::new(), 0u32, false);
    let mut buf = [0u8; 4096];
    while !done.load(Ordering::SeqCst) {
        let n = match port_rx.read(&mut buf) {
            Ok(n) => n,
            Err(_) => continue, // the poll's time-out
        };
        for p in rx.feed(&buf[..n]) {
            frames += 1;
            let Message::Command(cmd) = p.msg else {
                continue;
            };
            if silent {
                continue;
            }
            match cmd {
                Command::Configure(c) => tx.send(Message::Hello(Hello {
                    board: Board::Host,
                    firmware: [0, 1, 0],
                    state_dim: STATE_DIM as u8,
                    config: c,
                })),
                Command::Start(_) => {
                    tx.send(status(true, false, None, frames));
                    silent = script == Script::Silent;
                }
                Command::Replay(s) => {
                    if script == Script::ResumePastEnd && s.seq == 5 {
                        let r = Resume {
                            step: 0,
                            t_s: 0.0,
                            next_seq: 10_000,
                            generation: 1,
                        };
                        tx.send(status(false, true, Some(r), 0));
                    }
                    let same = window
                        .first()
                        .is_none_or(|t0| (t0 / PERIOD_S).floor() == (s.t_s / PERIOD_S).floor());
                    if !same && script != Script::FaultsThenDone {
                        tx.step(&mut window);
                    }
                    window.push(s.t_s);
                }
                Command::Finish => {
                    if script == Script::FaultsThenDone {
                        let f = Fault::new(FaultCode::Filter, 0, format_args!("update refused"));
                        tx.send(Message::Fault(f));
                    } else if !window.is_empty() {
                        tx.step(&mut window);
                    }
                    tx.send(status(false, false, None, frames));
                }
                _ => {}
            }
        }
    }
}

fn samples() -> Vec<RawSample> {
    (0..SAMPLES)
        .map(|k| RawSample {
            seq: k,
            t_s: f64::from(k),
            specific_force: [0.0, 0.0, 9.8],
            temp_c: f64::NAN,
        })
        .collect()
}

/// Replays [`samples`] into a fake firmware following `script`; returns the result and its
/// wall time.
fn replay_into(script: Script, silence: Duration) -> (anyhow::Result<ReplayOutcome>, Duration) {
    let pty = pty_pair().unwrap();
    let mut slave = pty.slave;
    slave.set_timeout(POLL).unwrap();
    let done = Arc::new(AtomicBool::new(false));
    let d = done.clone();
    let firmware = std::thread::spawn(move || fake_firmware(slave, script, d));
    let writer = writer_of(&pty.master).unwrap();
    let opts = ReplayOptions {
        config: Config {
            filter_period_s: PERIOD_S,
            ..Config::default()
        },
        timeout: Duration::from_secs(60),
        silence,
        ..ReplayOptions::default()
    };
    let t0 = Instant::now();
    let r = replay::replay(
        pty.master,
        writer,
        &samples(),
        &opts,
        || true,
        |_| Ok(()),
        |_| {},
    );
    let took = t0.elapsed();
    done.store(true, Ordering::SeqCst);
    firmware.join().unwrap();
    (r, took)
}

fn error_of(script: Script) -> String {
    let (r, _) = replay_into(script, Duration::from_secs(20));
    format!("{:#}", r.expect_err("the replay must fail"))
}

/// The harness itself: a well-behaved fake gives its ten estimates, in order, and no error —
/// so the failures below come from the misbehaviour, not from the fake.
#[test]
fn a_well_behaved_fake_firmware_gives_every_estimate() {
    let (r, _) = replay_into(Script::Good, Duration::from_secs(20));
    let out = r.unwrap();
    let steps: Vec<u32> = out.estimates.iter().map(|e| e.step).collect();
    assert_eq!(steps, (0..10).collect::<Vec<_>>());
    // The last window holds samples 540..=599: mean 569.5 s, exactly.
    assert_eq!(out.estimates[9].t_s, 569.5);
    assert!(out.faults.is_empty());
}

#[test]
fn faults_and_no_estimate_are_an_error_naming_the_fault() {
    let e = error_of(Script::FaultsThenDone);
    assert!(
        e.contains("after 0 estimates") && e.contains("Filter") && e.contains("update refused"),
        "{e}"
    );
}

#[test]
fn done_early_is_an_error_naming_what_is_missing() {
    let e = error_of(Script::DoneEarly);
    assert!(
        e.contains("done after 1 estimates (the last at t = 29.5 s)")
            && e.contains("goes on to t = 599.0 s")
            && e.contains("its end has no estimate"),
        "{e}"
    );
    // An estimate missing in the middle, not lost by the link (which counts what it loses).
    let e = error_of(Script::SkipsStep);
    assert!(
        e.contains("1 of its 10 update steps sent no estimate (the link lost 0 frames)"),
        "{e}"
    );
}

#[test]
fn a_resume_past_the_end_is_an_error_naming_the_sample() {
    let e = error_of(Script::ResumePastEnd);
    assert!(
        e.contains("sample 10000") && e.contains("does not have") && e.contains("0..=599"),
        "{e}"
    );
}

#[test]
fn estimates_the_firmware_could_not_compute_are_refused_by_name() {
    for (script, want) in [
        (
            Script::NanEstimate,
            "estimate 2 from the firmware (update step 1): its state DX0 = NaN",
        ),
        (Script::InfiniteNis, "update step 0): its NIS = inf"),
        (Script::NanTime, "update step 0): its time t_s = NaN s"),
    ] {
        let e = error_of(script);
        assert!(e.contains(want), "{script:?}: {e}");
    }
}

/// A firmware that stops answering used to keep the replay waiting until its time-out (an
/// hour by default); now the silence limit ends it, naming the sample being sent.
#[test]
fn a_firmware_that_stops_answering_is_named_after_the_silence_limit() {
    let silence = Duration::from_secs(1);
    let (r, took) = replay_into(Script::Silent, silence);
    let e = format!("{:#}", r.unwrap_err());
    assert!(
        e.contains("stopped answering") && e.contains("of 600"),
        "{e}"
    );
    // The limit, plus the reader's 0.1-s poll and the thread's start: 3 s is far from the 60-s
    // time-out, and far above the scheduling noise of a loaded machine.
    assert!(took < silence + Duration::from_secs(3), "took {took:?}");
}

/// `driftid replay` on the pty's slave, a fake firmware on its master: returns the exit code,
/// stderr and the estimates file if one was written.
fn replay_cli(script: Script, name: &str) -> (Option<i32>, String, Option<String>) {
    let dir =
        std::env::temp_dir().join(format!("driftid-replay-link-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let rec = dir.join("run.csv");
    let meta = host_tool::recording::Metadata {
        latitude_deg: Some(39.1),
        ..Default::default()
    };
    let rows: Vec<host_tool::recording::RawSample> = samples()
        .iter()
        .map(|s| host_tool::recording::RawSample {
            t_s: s.t_s,
            specific_force_mps2: s.specific_force,
            temp_c: None,
        })
        .collect();
    host_tool::recording::write_recording(&rec, &meta, &rows).unwrap();
    let pty = pty_pair().unwrap();
    let done = Arc::new(AtomicBool::new(false));
    let d = done.clone();
    let master = pty.master;
    let firmware = std::thread::spawn(move || fake_firmware(master, script, d));
    let out_csv = dir.join("estimates.csv");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_driftid"))
        .arg("replay")
        .arg(&rec)
        .args(["--port", &pty.slave_path, "--timeout-s", "60", "--out"])
        .arg(&out_csv)
        .output()
        .unwrap();
    done.store(true, Ordering::SeqCst);
    firmware.join().unwrap();
    let written = std::fs::read_to_string(&out_csv).ok();
    let _ = std::fs::remove_dir_all(&dir);
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
        written,
    )
}

/// The exit codes the command gives: faults with every estimate there are "computed but not
/// trusted" (3, the estimates written, the fault named); an estimate the firmware could not
/// compute is an error (2) and nothing is written — not half a file.
#[test]
fn the_command_exits_3_on_faults_and_2_on_a_nan_estimate_writing_nothing() {
    let (code, err, written) = replay_cli(Script::FaultMidRun, "fault");
    assert_eq!(code, Some(3), "{err}");
    assert!(
        err.contains("Filter at update step 2: update refused"),
        "{err}"
    );
    let rows = written.expect("the estimates are written").lines().count();
    assert_eq!(rows, 1 + 10, "header and the ten estimates");
    let (code, err, written) = replay_cli(Script::NanEstimate, "nan");
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("state DX0 = NaN"), "{err}");
    assert_eq!(written, None, "no output at all");
}
