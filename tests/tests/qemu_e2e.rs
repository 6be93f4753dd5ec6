//! End-to-end tests of the firmware under QEMU (`cargo test qemu` runs exactly these).
//!
//! Each test builds the firmware for QEMU's `mps2-an500` (Cortex-M7, double-precision FPU),
//! creates a pseudo-terminal pair, boots QEMU with its UART0 on the pty's slave, and replays a
//! simulated recording of the paper's scenario over the link (`host_tool::link::replay`, what
//! `driftid replay` runs). They FAIL, never skip, when `qemu-system-arm` or the
//! `thumbv7em-none-eabihf` target is missing (`.ci/qemu.sh` installs both).
//!
//! 1. `qemu_replay_matches_host_single_pass`: the firmware's estimates, received over the link,
//!    equal the host core's single pass on the same samples, step by step.
//! 2. `qemu_link_corruption_costs_only_damaged_frames`: bytes flipped, dropped, truncated on the
//!    link in both directions cost exactly the damaged frames, and both ends count them.

use std::io::{self, Read, Write};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use host_tool::link::port::pty_pair;
use host_tool::link::replay::{self, ReplayOptions, ReplayOutcome};
use host_tool::simulate::{simulate, Scenario};
use protocol::{Config, Estimate, RawSample};
use tests::firmware::{host_single_pass_counted, qemu_elf as firmware};

struct Qemu {
    child: Child,
}

impl Qemu {
    /// Boots the firmware with UART0 on `serial`; `-icount shift=0`: one instruction per virtual
    /// nanosecond, so the firmware's SysTick counts measure instructions exactly.
    fn boot(serial: &str) -> Qemu {
        let child = Command::new("qemu-system-arm")
            .args(["-M", "mps2-an500", "-display", "none", "-monitor", "none"])
            .args([
                "-semihosting-config",
                "enable=on,target=native",
                "-icount",
                "shift=0",
            ])
            .args(["-serial", serial, "-kernel"])
            .arg(firmware())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starting qemu-system-arm");
        Qemu { child }
    }

    fn alive(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }

    /// Waits for QEMU to exit (the firmware's semihosting exit code); returns (code, output).
    fn wait(mut self, timeout: Duration) -> (Option<i32>, String) {
        let t = Instant::now();
        while self.alive() && t.elapsed() < timeout {
            std::thread::sleep(Duration::from_millis(20));
        }
        if self.alive() {
            let _ = self.child.kill();
        }
        let out = std::mem::replace(&mut self.child, Command::new("true").spawn().unwrap())
            .wait_with_output()
            .unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        (out.status.code(), text)
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The paper's scenario, 4 h at 1 s (14 401 samples, 240 filter updates of 60 s).
fn input() -> (Config, Vec<RawSample>) {
    static INPUT: OnceLock<(Config, Vec<RawSample>)> = OnceLock::new();
    INPUT
        .get_or_init(|| {
            let sc = Scenario {
                hours: 4.0,
                ..Scenario::paper()
            };
            let sim = simulate(&sc);
            let base = Config {
                filter_period_s: 60.0,
                raw_sigma_mps2: [sc.accel_sigma_mps2 * (60.0f64 / sc.rate_s).sqrt(); 3],
                arw_deg2_per_h: sc.arw_deg2_per_h,
                status_every: 0,
                ..Config::default()
            };
            (
                replay::config_for(&sim.meta, base).unwrap(),
                replay::link_samples(&sim.samples),
            )
        })
        .clone()
}

/// Runs one replay through QEMU; `wrap_w`/`wrap_r` may damage the two directions.
fn run_qemu<R: Read, W: Write + Send + 'static>(
    samples: &[RawSample],
    config: Config,
    wrap_r: impl FnOnce(Box<dyn Read + Send>) -> R,
    wrap_w: impl FnOnce(Box<dyn Write + Send>) -> W,
) -> (ReplayOutcome, f64) {
    let pty = pty_pair().unwrap();
    let mut qemu = Qemu::boot(&pty.slave_path);
    // The sending side waits while QEMU is busy (a short write timeout would cut the stream).
    let writer = host_tool::link::port::writer_of(&pty.master).unwrap();
    let t = Instant::now();
    let opts = ReplayOptions {
        config,
        shutdown: true,
        timeout: Duration::from_secs(300),
        ..ReplayOptions::default()
    };
    let reader: Box<dyn Read + Send> = Box::new(pty.master);
    let outcome = replay::replay(
        wrap_r(reader),
        wrap_w(Box::new(writer)),
        samples,
        &opts,
        || qemu.alive(),
        |_| Ok(()),
        |_| {},
    );
    let (code, text) = qemu.wait(Duration::from_secs(30));
    drop(pty.slave);
    let outcome = outcome.unwrap_or_else(|e| panic!("replay failed: {e:#}\nQEMU output:\n{text}"));
    assert_eq!(
        code,
        Some(0),
        "QEMU must exit with the firmware's success code after Shutdown; output:\n{text}"
    );
    (outcome, t.elapsed().as_secs_f64())
}

#[test]
fn qemu_replay_matches_host_single_pass() {
    let (config, samples) = input();
    let (want, counts) = host_single_pass_counted(&config, &samples);
    let (got, secs) = run_qemu(&samples, config, |r| r, |w| w);
    assert!(got.faults.is_empty(), "firmware faults: {:?}", got.faults);
    assert_eq!(
        got.estimates.len(),
        want.len(),
        "one estimate per filter period"
    );
    assert_eq!(want.len(), 241);

    // Tolerance. Both ends run the same source (estimator-core) on IEEE-754 binary64 with
    // round-to-nearest: the firmware on the Cortex-M7's double-precision FPU (VFPv5), the host
    // on x86-64 SSE2. Rust never contracts a*b+c into an FMA on its own, and the core calls libm
    // for every transcendental function on both targets, so the operations — and the results —
    // are the same unless the compiler reassociates (it does not for floats). The remaining
    // possible difference is `sqrt` (x86 `sqrtsd` vs VFP `vsqrt.f64`; both correctly rounded).
    // Measured: bit-identical on all 241 updates. We still allow 1e-12 relative (state: relative
    // to its 1σ) so a future libm/FMA difference is reported as a figure, not a mystery: that is
    // 1e-12 σ, thousands of times below anything that affects the estimates.
    let mut max_state = 0.0f64;
    let mut max_sigma = 0.0f64;
    let mut bit_identical = true;
    for (g, w) in got.estimates.iter().zip(&want) {
        assert_eq!((g.step, g.samples), (w.step, w.samples));
        assert_eq!(
            g.t_s.to_bits(),
            w.t_s.to_bits(),
            "time tag of step {}",
            w.step
        );
        for i in 0..15 {
            max_state = max_state.max((g.state[i] - w.state[i]).abs() / w.sigma[i]);
            max_sigma = max_sigma.max((g.sigma[i] - w.sigma[i]).abs() / w.sigma[i]);
        }
        bit_identical &= g == w;
    }
    eprintln!(
        "QEMU replay: {} samples, {} estimates in {:.1} s; max |Δstate|/σ = {:.3e}, max |Δσ|/σ = {:.3e}, bit-identical: {}",
        samples.len(),
        got.estimates.len(),
        secs,
        max_state,
        max_sigma,
        bit_identical
    );
    assert!(
        max_state <= 1e-12 && max_sigma <= 1e-12,
        "firmware and host differ: {max_state:e} {max_sigma:e}"
    );

    let st = got.final_status().expect("final status");
    let c = &st.counters;
    // The firmware's screening counts what the shared code counts for the same samples ...
    let screened = |c: &protocol::Counters| {
        (
            c.samples_ok,
            c.samples_nan,
            c.samples_saturated,
            c.samples_out_of_order,
            c.samples_duplicate,
            c.samples_stuck,
            c.samples_glitch,
            c.samples_dropout,
        )
    };
    assert_eq!(screened(c), screened(&counts));
    // ... and the simulated recording is clean: nothing rejected.
    assert_eq!(counts.samples_ok as usize, samples.len(), "{counts:?}");
    assert_eq!(
        (
            c.filter_steps as usize,
            c.filter_errors,
            c.frames_rx_bad,
            c.frames_rx_missing
        ),
        (want.len(), 0, 0, 0)
    );
    assert_eq!(got.rx.lost(), 0);
    // Figures: stack high-water, static RAM, instructions per update (icount: 1 instr = 1 ns).
    let instr = f64::from(st.last_step_ticks) * 1e9 / f64::from(st.tick_hz);
    eprintln!(
        "firmware: stack high-water {} of {} bytes, static RAM {} bytes, last EKF update {} ticks = {:.0} instructions",
        st.stack_used_bytes, st.stack_size_bytes, st.static_ram_bytes, st.last_step_ticks, instr
    );
    // The budget for the link loop's stack (the self-test's is enforced by .ci/qemu.sh).
    assert!(
        st.stack_used_bytes > 0 && st.stack_used_bytes <= 16 * 1024,
        "stack {}",
        st.stack_used_bytes
    );
    assert!(
        instr > 1e3 && instr < 1e7,
        "instructions per update {instr}"
    );
}

/// Damages chosen frames written to the firmware (one `write_all` per frame).
struct DamageWriter<W> {
    inner: W,
    frame: usize,
    /// (frame index, kind): 0 flip, 1 drop a byte, 2 truncate (closing delimiter lost).
    plan: Vec<(usize, u8)>,
}

impl<W: Write> Write for DamageWriter<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.inner.write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        let i = self.frame;
        self.frame += 1;
        let Some(&(_, kind)) = self.plan.iter().find(|(f, _)| *f == i) else {
            return self.inner.write_all(buf);
        };
        let mut f = buf.to_vec();
        let mid = f.len() / 2;
        match kind {
            0 => {
                // flip one bit of a content byte (never into a delimiter)
                let bit = if f[mid] ^ 0x04 == 0 { 0x08 } else { 0x04 };
                f[mid] ^= bit;
            }
            1 => {
                f.remove(mid);
            }
            _ => f.truncate(mid),
        }
        self.inner.write_all(&f)
    }
}

/// Flips one content byte in chosen frames coming from the firmware.
struct DamageReader<R> {
    inner: R,
    frame: usize,
    pos_in_frame: usize,
    plan: Vec<usize>,
}

impl<R: Read> Read for DamageReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.inner.read(buf)?;
        for b in &mut buf[..n] {
            if *b == 0 {
                if self.pos_in_frame > 0 {
                    self.frame += 1;
                }
                self.pos_in_frame = 0;
                continue;
            }
            self.pos_in_frame += 1;
            if self.pos_in_frame == 5 && self.plan.contains(&self.frame) {
                *b ^= if *b ^ 0x10 == 0 { 0x20 } else { 0x10 };
            }
        }
        Ok(n)
    }
}

#[test]
fn qemu_link_corruption_costs_only_damaged_frames() {
    let (config, all) = input();
    let samples = &all[..3 * 3600 + 1];
    // Host → firmware: frames 0 and 1 are Configure and Start; sample k is frame k + 2.
    // Damage 30 sample frames spread over the run, cycling flip / drop / truncate.
    let damaged: Vec<usize> = (0..30).map(|j| 50 + j * 347).collect();
    let plan: Vec<(usize, u8)> = damaged
        .iter()
        .enumerate()
        .map(|(j, &k)| (k + 2, (j % 3) as u8))
        .collect();
    // Firmware → host: frames 0..3 are Hello, Status (boot), Hello (Configure), Status (Start);
    // then one Estimate per filter period. Damage 9 estimate frames.
    let rx_plan: Vec<usize> = (0..9).map(|j| 10 + j * 17).collect();
    let (got, _) = run_qemu(
        samples,
        config,
        |r| DamageReader {
            inner: r,
            frame: 0,
            pos_in_frame: 0,
            plan: rx_plan.clone(),
        },
        |w| DamageWriter {
            inner: w,
            frame: 0,
            plan: plan.clone(),
        },
    );

    // Firmware side: exactly the damaged frames lost and counted, every other sample used.
    let st = got.final_status().expect("final status");
    let c = &st.counters;
    assert_eq!(
        c.frames_rx_bad as usize,
        damaged.len(),
        "damaged frames counted by the firmware"
    );
    assert_eq!(
        c.frames_rx_missing as usize,
        damaged.len(),
        "sequence gaps seen by the firmware"
    );
    assert_eq!(c.samples_ok as usize, samples.len() - damaged.len());
    assert_eq!(c.frames_rx as usize, samples.len() - damaged.len() + 3);
    // ... and the estimates are the host's single pass on the samples that were not damaged.
    let kept: Vec<RawSample> = samples
        .iter()
        .enumerate()
        .filter(|(k, _)| !damaged.contains(k))
        .map(|(_, s)| *s)
        .collect();
    let (want, counts) = host_single_pass_counted(&config, &kept);
    assert_eq!(counts.samples_ok, c.samples_ok);

    // Host side: exactly the damaged estimate frames lost, counted by the decoder and by sequence.
    assert_eq!(got.rx.decoder.bad() as usize, rx_plan.len(), "{}", got.rx);
    assert_eq!(got.rx.missing as usize, rx_plan.len(), "{}", got.rx);
    assert_eq!(got.estimates.len(), want.len() - rx_plan.len());
    let lost_steps: Vec<u32> = rx_plan.iter().map(|&f| (f - 4) as u32).collect();
    let expected: Vec<&Estimate> = want
        .iter()
        .filter(|e| !lost_steps.contains(&e.step))
        .collect();
    for (g, w) in got.estimates.iter().zip(expected) {
        assert_eq!(g, w, "estimate of step {}", w.step);
    }
    eprintln!(
        "corruption: firmware lost {} of {} host frames (counted bad {}, missing {}); host lost {} estimates: {}",
        damaged.len(),
        samples.len() + 3,
        c.frames_rx_bad,
        c.frames_rx_missing,
        rx_plan.len(),
        got.rx
    );
}
