//! Progress for long runs: drawn on a terminal (stderr), silent when piped or redirected.

use std::sync::LazyLock;
use std::time::{Duration, Instant};

/// When the process started ([`start_clock`]; else the first timed note).
static START: LazyLock<Instant> = LazyLock::new(Instant::now);

/// Starts the clock `DRIFTID_TIMING`'s notes are timed from (call first thing in `main`).
pub fn start_clock() {
    LazyLock::force(&START);
}

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar of `len` steps with a message; hidden unless stderr is a terminal.
pub(crate) fn bar(len: u64, msg: &str) -> ProgressBar {
    let pb = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ({elapsed}, eta {eta})")
            .unwrap()
            .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}

/// Notes of the library's steps ([`crate::steps::Progress`]) as `pb`'s message; nothing when
/// `pb` is hidden (stderr not a terminal), so a redirected run formats no message at all.
///
/// With `DRIFTID_TIMING` set in the environment each note is also written to stderr with the
/// seconds since the process started, the CPU time and the passes over the measurements so far
/// ([`crate::identify::work`]; where the time of a run goes: docs/measurements.md).
pub(crate) fn follow(pb: &ProgressBar) -> crate::steps::Progress {
    if std::env::var_os("DRIFTID_TIMING").is_some() {
        let start = *START;
        return crate::steps::Progress::new(move |m| {
            eprintln!(
                "[{:7.3} s, CPU {:7.3} s; {}] {m}",
                start.elapsed().as_secs_f64(),
                process_cpu_s(),
                crate::identify::work::so_far()
            )
        });
    }
    if pb.is_hidden() {
        return crate::steps::Progress::default();
    }
    let pb = pb.clone();
    crate::steps::Progress::new(move |m| pb.set_message(m.to_string()))
}

/// The process's CPU time so far, all threads (`DRIFTID_TIMING`'s notes: a phase whose CPU grows
/// no faster than its wall time leaves the second core idle). NaN where it cannot be read.
fn process_cpu_s() -> f64 {
    #[cfg(unix)]
    {
        let mut t = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `t` is a valid, writable timespec; the call only writes it.
        if unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) } == 0 {
            return t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9;
        }
    }
    f64::NAN
}

/// A spinner with a message that the caller updates; hidden unless stderr is a terminal.
pub(crate) fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    pb.set_style(ProgressStyle::with_template("{spinner} {msg} ({elapsed})").unwrap());
    pb.set_message(msg.to_string());
    // indicatif's steady tick is a thread of its own, started (and joined when the spinner
    // finishes) even for a hidden spinner: only on a terminal.
    if !pb.is_hidden() {
        pb.enable_steady_tick(Duration::from_millis(120));
    }
    pb
}
