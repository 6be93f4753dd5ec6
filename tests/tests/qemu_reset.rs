//! Resets under QEMU (`cargo test qemu` runs these): the firmware, booted in QEMU, replays a
//! simulated recording with checkpoints every 10 filter updates; the QEMU monitor resets the
//! machine (`system_reset`) at seeded random updates during the run. After each reset the
//! firmware resumes from its newest checkpoint (QEMU-backed flash) and the host replay goes on
//! from the checkpoint's sample; one reset comes before the first checkpoint, so the firmware
//! restarts from scratch. The final estimates must equal an uninterrupted host single pass.
//! Fails, never skips, when qemu-system-arm or the thumbv7em target is missing.

use std::io::Write;
use std::os::unix::net::UnixStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use host_tool::link::port::{pty_pair, writer_of};
use host_tool::link::replay::{self, ReplayOptions};
use host_tool::simulate::{simulate, Scenario};
use protocol::{Config, FaultCode, Message};
use tests::firmware::{host_single_pass, qemu_elf};

struct Qemu(Child);
impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Seeded update numbers at which to reset: one before the first checkpoint (update 10), the
/// rest spread over the run, increasing.
fn reset_points(seed: u64, n: usize, updates: u32) -> Vec<u32> {
    let mut s = seed;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 33) as u32
    };
    let mut v = vec![3 + next() % 4];
    let span = (updates - 30) / n as u32;
    for k in 0..n {
        v.push(20 + k as u32 * span + next() % span);
    }
    v
}

#[test]
fn qemu_resets_at_random_points_end_with_the_uninterrupted_estimates() {
    let elf = qemu_elf();
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
        checkpoint_every: 10,
        ..Config::default()
    };
    let config = replay::config_for(&sim.meta, base).unwrap();
    let samples = replay::link_samples(&sim.samples);
    let want = host_single_pass(&config, &samples);
    assert_eq!(want.len(), 241);
    let resets = reset_points(20261123, 4, want.len() as u32);

    let pty = pty_pair().unwrap();
    let sock =
        std::env::temp_dir().join(format!("driftid-qemu-monitor-{}.sock", std::process::id()));
    let _ = std::fs::remove_file(&sock);
    let child = Command::new("qemu-system-arm")
        .args(["-M", "mps2-an500", "-display", "none"])
        .args([
            "-semihosting-config",
            "enable=on,target=native",
            "-icount",
            "shift=0",
        ])
        .arg("-monitor")
        .arg(format!("unix:{},server=on,wait=off", sock.display()))
        .args(["-serial", &pty.slave_path, "-kernel"])
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("starting qemu-system-arm");
    let mut qemu = Qemu(child);
    let t0 = Instant::now();
    let mut monitor = loop {
        match UnixStream::connect(&sock) {
            Ok(s) => break s,
            Err(_) if t0.elapsed() < Duration::from_secs(20) => {
                std::thread::sleep(Duration::from_millis(50))
            }
            Err(e) => panic!("QEMU monitor socket {}: {e}", sock.display()),
        }
    };
    let writer = writer_of(&pty.master).unwrap();
    let opts = ReplayOptions {
        config,
        shutdown: true,
        timeout: Duration::from_secs(600),
        ..ReplayOptions::default()
    };
    let mut pending = resets.clone();
    let mut fired = Vec::new();
    let outcome = replay::replay(
        pty.master,
        writer,
        &samples,
        &opts,
        || matches!(qemu.0.try_wait(), Ok(None)),
        |_| Ok(()),
        |m| {
            if let Message::Estimate(e) = m {
                if pending.first() == Some(&e.step) {
                    pending.remove(0);
                    fired.push(e.step);
                    monitor.write_all(b"system_reset\n").expect("QEMU monitor");
                }
            }
        },
    )
    .unwrap_or_else(|e| panic!("replay with resets failed: {e:#}"));
    let secs = t0.elapsed().as_secs_f64();
    drop(pty.slave);
    let _ = std::fs::remove_file(&sock);

    assert_eq!(fired, resets, "every planned reset happened");
    assert_eq!(
        outcome.resets.len(),
        resets.len(),
        "the host saw every reset: {:?}",
        outcome.resets
    );
    // The first reset (before update 10) finds only the "run started" marker: a restart.
    assert!(outcome.resets[0].is_none(), "{:?}", outcome.resets[0]);
    for (r, &at) in outcome.resets[1..].iter().zip(&resets[1..]) {
        let r = r.expect("resumed from a checkpoint");
        // Checkpoints follow every 10th update; the newest is at most 10 updates behind the
        // reset. The host triggers the reset when it *receives* update `at`; the firmware may be
        // a few updates further by then (link latency), hence the window above `at` too.
        assert!(
            r.step % 10 == 0 && r.step + 10 > at && r.step <= at + 10,
            "reset after update {at}: resumed at {}",
            r.step
        );
    }
    // Bit-identical to the uninterrupted run: the checkpoint holds the exact f64 state at a
    // window boundary and the same samples are resent, so no tolerance is needed; any lost or
    // duplicated sample would change the estimates.
    assert_eq!(
        outcome.estimates.len(),
        want.len(),
        "one estimate per update, none lost or repeated"
    );
    for (g, w) in outcome.estimates.iter().zip(&want) {
        assert_eq!(g, w, "estimate of update {}", w.step);
    }
    // Faults: only the refusals of stale samples that reached the restarted (idle) firmware.
    assert!(
        outcome
            .faults
            .iter()
            .all(|f| f.code == FaultCode::BadCommand),
        "{:?}",
        outcome.faults.first()
    );
    let st = outcome.final_status().unwrap();
    eprintln!(
        "QEMU resets: {} resets after updates {:?}, resumed {:?}; {} samples, {} estimates identical to the uninterrupted run; \
         after the last reset: {} checkpoints written, {} stale frames discarded; {:.1} s",
        resets.len(),
        resets,
        outcome.resets.iter().map(|r| r.map(|r| r.step)).collect::<Vec<_>>(),
        samples.len(),
        outcome.estimates.len(),
        st.counters.checkpoints_written,
        st.counters.samples_resync,
        secs
    );
    let _ = qemu.0.wait();
}
