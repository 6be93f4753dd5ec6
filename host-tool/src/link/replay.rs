//! Hardware-in-the-loop replay: stream a recording into the firmware over the link and collect
//! what comes back.
//!
//! A writer thread sends `Configure`, `Start(Replay)`, one `Replay` frame per sample, `Finish`
//! (one `write_all` per frame); the calling thread reads concurrently (the firmware blocks on
//! output while the host does not read, so reading and writing must overlap). The run ends at the
//! first `Status` saying "not running" after `Finish` went out; then, if asked, `Shutdown`.
//!
//! Every way the run can go wrong ends it with an error naming what happened: an estimate the
//! firmware could not compute (NaN state or time, infinite NIS), a run the firmware ended before
//! the recording's end or resumed from a checkpoint past it, estimates missing at the end, a
//! firmware silent for [`ReplayOptions::silence`], the time-out ([`ReplayOptions::timeout`],
//! which holds for writes too: the writer never blocks past it). Faults the firmware reports are
//! kept in the outcome for the caller to judge.
//!
//! Resets: when the firmware reboots during the run (a boot `Status`), the replay goes on from
//! where the firmware can: from the checkpoint's sample (`Status::resumed.next_seq`), or from the
//! start (`Configure`, `Start`) when it had no checkpoint. Estimates the resumed firmware will
//! send again (step ≥ the checkpoint's) are dropped from the outcome, so it holds each update
//! once, as the uninterrupted run would.

use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _};
use protocol::{
    Command, Config, Encoder, Estimate, Fault, Hello, Message, RawSample, Source, Status,
};

use super::port::{is_gone, is_timeout, WRITE_TIMEOUT};
use super::{LinkStats, Receiver};
use crate::recording;

/// How to replay.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    /// The firmware configuration for the run.
    pub config: Config,
    /// Send `Shutdown` after the run (QEMU then exits with success).
    pub shutdown: bool,
    /// Give up after this long.
    pub timeout: Duration,
    /// Give up when nothing arrives from the firmware for this long (it stopped answering).
    pub silence: Duration,
}

/// Default of [`ReplayOptions::silence`]: the firmware answers every filter period's samples
/// with an estimate, in well under a second on a link of 115 200 Bd with 1-Hz samples.
pub(crate) const DEFAULT_SILENCE: Duration = Duration::from_secs(60);

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            config: Config::default(),
            shutdown: false,
            timeout: Duration::from_secs(600),
            silence: DEFAULT_SILENCE,
        }
    }
}

/// What came back.
#[derive(Clone, Debug, Default)]
pub struct ReplayOutcome {
    /// The firmware's identification (boot or after `Configure`), the last one seen.
    pub hello: Option<Hello>,
    /// Every estimate, in order.
    pub estimates: Vec<Estimate>,
    /// Every status.
    pub statuses: Vec<Status>,
    /// Every fault.
    pub faults: Vec<Fault>,
    /// Frames sent by the host.
    pub frames_sent: u64,
    /// Loss accounting of the firmware → host direction.
    pub rx: LinkStats,
    /// Wall time of the run, s.
    pub elapsed_s: f64,
    /// Firmware resets seen during the run, with what each resumed from (`None`: restarted).
    pub resets: Vec<Option<protocol::Resume>>,
}

impl ReplayOutcome {
    /// The status that ended the run (the firmware's counters after `Finish`).
    pub fn final_status(&self) -> Option<&Status> {
        self.statuses.last()
    }
}

/// Converts a recording's samples to link samples (numbered from 0; NaN for no temperature).
pub fn link_samples(samples: &[recording::RawSample]) -> Vec<RawSample> {
    samples
        .iter()
        .enumerate()
        .map(|(i, s)| RawSample {
            seq: i as u32,
            t_s: s.t_s,
            specific_force: s.specific_force_mps2,
            temp_c: s.temp_c.unwrap_or(f64::NAN),
        })
        .collect()
}

/// The firmware configuration for a recording: its latitude and gravity, the rest from `base`.
pub fn config_for(meta: &recording::Metadata, base: Config) -> anyhow::Result<Config> {
    let latitude_deg = meta
        .latitude_deg
        .context("the recording has no latitude_deg")?;
    Ok(Config {
        latitude_deg,
        gravity_mps2: meta.gravity_mps2.or(base.gravity_mps2),
        ..base
    })
}

/// Replays `samples` over a link. `reader`/`writer` are the two directions of one port (e.g. a
/// port and its `try_clone`); `alive` says whether the other end still runs (checked while
/// waiting); `on_msg` sees every received message (progress display, raw logging).
///
/// The writer runs on a thread of its own, one `write_all` per frame. When the run fails (the
/// time-out included) while that thread is blocked in a write to a firmware that does not read,
/// the replay returns its error at once and leaves the thread to end with its write's own
/// time-out ([`super::port::WRITE_TIMEOUT`]): the time-out holds for writes too.
pub fn replay<R: Read, W: Write + Send + 'static>(
    reader: R,
    writer: W,
    samples: &[RawSample],
    opts: &ReplayOptions,
    alive: impl FnMut() -> bool,
    on_bytes: impl FnMut(&[u8]) -> anyhow::Result<()>,
    on_msg: impl FnMut(&Message),
) -> anyhow::Result<ReplayOutcome> {
    let start = Instant::now();
    let link = Arc::new(Link {
        samples: samples.to_vec(),
        opts: opts.clone(),
        deadline: start + opts.timeout,
        finish_sent: AtomicBool::new(false),
        stop: AtomicBool::new(false),
        sent_frames: AtomicU64::new(0),
        sent_samples: AtomicU64::new(0),
    });
    let (ctl_tx, ctl_rx) = mpsc::channel::<Ctl>();
    let mut out = ReplayOutcome::default();
    let mut rx = Receiver::new();
    let writer_thread = std::thread::spawn({
        let link = Arc::clone(&link);
        move || write_run(&link, writer, ctl_rx)
    });
    let io = ReadIo {
        reader,
        alive,
        on_bytes,
        on_msg,
    };
    let result = read_run(&link, io, &mut out, &mut rx, &ctl_tx, || {
        writer_thread.is_finished()
    });
    if result.is_err() {
        link.stop.store(true, Ordering::SeqCst);
    }
    let _ = ctl_tx.send(Ctl::Done(result.is_ok()));
    match (
        result,
        end_writer(writer_thread, link.stop.load(Ordering::SeqCst)),
    ) {
        // The writer's own failure (the firmware does not read) is the cause the reader saw.
        (Err(e), Some(Err(w))) if e.to_string().contains(WRITER_ENDED) => return Err(w),
        (Err(e), _) => return Err(e),
        (Ok(()), None) => bail!("internal error: the writer to the link did not end"),
        (Ok(()), Some(sent)) => out.frames_sent = sent?,
    }
    check_complete(
        samples,
        opts.config.filter_period_s,
        &out,
        rx.stats().lost(),
    )?;
    out.rx = rx.stats();
    out.elapsed_s = start.elapsed().as_secs_f64();
    Ok(out)
}

/// How long a failed run waits for its writer to end before leaving it blocked in a write.
const WRITER_GRACE: Duration = Duration::from_millis(500);

/// Ends the writer thread: joined when the run succeeded (it sends `Shutdown`, to a firmware
/// that reads) or when it ends within [`WRITER_GRACE`]; `None` if it is still blocked in a write
/// after a failure (left to end with that write's time-out).
fn end_writer(
    t: std::thread::JoinHandle<anyhow::Result<u64>>,
    failed: bool,
) -> Option<anyhow::Result<u64>> {
    let t0 = Instant::now();
    while failed && !t.is_finished() {
        if t0.elapsed() > WRITER_GRACE {
            return None;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Some(
        t.join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("the writer thread panicked"))),
    )
}

/// What the writer and the reader of one run share.
struct Link {
    samples: Vec<RawSample>,
    opts: ReplayOptions,
    deadline: Instant,
    /// `Finish` is (being) sent: a "not running" status now ends the run.
    finish_sent: AtomicBool,
    /// The run failed: the writer stops at once, even in the middle of a frame.
    stop: AtomicBool,
    sent_frames: AtomicU64,
    /// Index of the next sample to send.
    sent_samples: AtomicU64,
}

/// Said by the reader when the writer ended on its own (it failed).
const WRITER_ENDED: &str = "the writer to the link ended";

/// The writer thread: `Configure`, `Start`, the samples, `Finish`; resets followed as the
/// reader says. Returns the frames sent.
fn write_run<W: Write>(link: &Link, mut w: W, ctl_rx: mpsc::Receiver<Ctl>) -> anyhow::Result<u64> {
    let (samples, config) = (&link.samples[..], link.opts.config);
    let mut enc = Encoder::new();
    let mut send = |w: &mut W, cmd: Command| -> anyhow::Result<()> {
        let f = enc
            .frame(Message::Command(cmd))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        link.sent_frames.fetch_add(1, Ordering::SeqCst);
        write_frame(w, f, link)
    };
    send(&mut w, Command::Configure(config))?;
    send(&mut w, Command::Start(Source::Replay))?;
    let mut i = 0usize;
    loop {
        // Control from the reader: a reset to follow, or the end.
        let ctl = if i <= samples.len() {
            ctl_rx.try_recv().ok()
        } else {
            Some(ctl_rx.recv().unwrap_or(Ctl::Done(false)))
        };
        match ctl {
            Some(Ctl::Done(ok)) => {
                if ok && link.opts.shutdown {
                    send(&mut w, Command::Shutdown)?;
                    w.flush().context("flushing the link")?;
                }
                break;
            }
            Some(Ctl::ResendFrom(seq)) => {
                link.finish_sent.store(false, Ordering::SeqCst);
                i = samples
                    .iter()
                    .position(|s| s.seq == seq)
                    .unwrap_or(samples.len());
                continue;
            }
            Some(Ctl::Restart) => {
                link.finish_sent.store(false, Ordering::SeqCst);
                send(&mut w, Command::Configure(config))?;
                send(&mut w, Command::Start(Source::Replay))?;
                i = 0;
                continue;
            }
            None => {}
        }
        link.sent_samples.store(i as u64, Ordering::SeqCst);
        if i < samples.len() {
            send(&mut w, Command::Replay(samples[i]))?;
        } else {
            // Set first: the firmware's answer may come before the write returns. No flush: a
            // tty's flush waits for the other end to read, which it may never do.
            link.finish_sent.store(true, Ordering::SeqCst);
            send(&mut w, Command::Finish)?;
        }
        i += 1;
    }
    Ok(link.sent_frames.load(Ordering::SeqCst))
}

/// Writes one frame whole (one `write_all`: tests damage frames by it), unless the run failed
/// or its deadline passed. The writer's own time-out ([`WRITE_TIMEOUT`]) ends a write to a
/// firmware that reads nothing.
fn write_frame<W: Write>(w: &mut W, f: &[u8], link: &Link) -> anyhow::Result<()> {
    if link.stop.load(Ordering::SeqCst) {
        bail!("the replay stopped");
    }
    if Instant::now() > link.deadline {
        bail!(
            "replay timed out after {:?} while writing to the link ({} frames sent)",
            link.opts.timeout,
            link.sent_frames.load(Ordering::SeqCst)
        );
    }
    match w.write_all(f) {
        Ok(()) => Ok(()),
        Err(e) if is_timeout(&e) => bail!(
            "the firmware has read nothing for {WRITE_TIMEOUT:?} ({} frames sent): it stopped reading",
            link.sent_frames.load(Ordering::SeqCst)
        ),
        Err(e) if is_gone(&e) => bail!("the link went away while writing: {e}"),
        Err(e) => Err(e).context("writing to the link"),
    }
}

/// The reading side's inputs and callbacks.
struct ReadIo<R, A, B, M> {
    reader: R,
    alive: A,
    on_bytes: B,
    on_msg: M,
}

/// The reader: collects what the firmware sends until the run ends (a "not running" status
/// after `Finish`), or fails naming why.
fn read_run<R: Read>(
    link: &Link,
    mut io: ReadIo<
        R,
        impl FnMut() -> bool,
        impl FnMut(&[u8]) -> anyhow::Result<()>,
        impl FnMut(&Message),
    >,
    out: &mut ReplayOutcome,
    rx: &mut Receiver,
    ctl_tx: &mpsc::Sender<Ctl>,
    writer_ended: impl Fn() -> bool,
) -> anyhow::Result<()> {
    let opts = &link.opts;
    let mut buf = [0u8; 4096];
    let mut started = false;
    let mut last_rx = Instant::now();
    loop {
        if Instant::now() > link.deadline {
            bail!(
                "replay timed out after {:?} ({} estimates received)",
                opts.timeout,
                out.estimates.len()
            );
        }
        if writer_ended() {
            bail!("{WRITER_ENDED} before the run did");
        }
        if last_rx.elapsed() > opts.silence {
            bail!(
                "the firmware stopped answering: nothing received for {:?}, with sample {} of {} being sent ({} estimates received{})",
                opts.silence,
                link.sent_samples.load(Ordering::SeqCst),
                link.samples.len(),
                out.estimates.len(),
                out.estimates
                    .last()
                    .map(|e| format!(", the last step {} at t = {:?} s", e.step, e.t_s))
                    .unwrap_or_default()
            );
        }
        let n = match io.reader.read(&mut buf) {
            Ok(0) => 0,
            Ok(n) => n,
            Err(e) if is_timeout(&e) => 0,
            Err(e) if is_gone(&e) => bail!("the link went away: {e}"),
            Err(e) => return Err(e).context("reading from the link"),
        };
        if n == 0 {
            if !(io.alive)() {
                bail!("the firmware ended before the replay finished");
            }
            continue;
        }
        last_rx = Instant::now();
        (io.on_bytes)(&buf[..n])?;
        let mut end = false;
        for p in rx.feed(&buf[..n]) {
            (io.on_msg)(&p.msg);
            end |= take(link, p.msg, out, &mut started, ctl_tx)?;
        }
        if end {
            return Ok(());
        }
    }
}

/// Takes one message into the outcome; `Ok(true)`: the run ended.
fn take(
    link: &Link,
    msg: Message,
    out: &mut ReplayOutcome,
    started: &mut bool,
    ctl_tx: &mpsc::Sender<Ctl>,
) -> anyhow::Result<bool> {
    match msg {
        Message::Hello(h) => out.hello = Some(h),
        Message::Estimate(e) => {
            if let Some(p) = estimate_problem(&e) {
                bail!(
                    "estimate {} from the firmware (update step {}): {p}; refusing to keep estimates the firmware could not compute",
                    out.estimates.len() + 1,
                    e.step
                );
            }
            out.estimates.push(e)
        }
        Message::Fault(f) => out.faults.push(f),
        Message::Status(s) if s.boot && *started => {
            // The firmware rebooted mid-run: go on from its checkpoint, or restart.
            out.resets.push(s.resumed);
            match s.resumed {
                Some(r) => {
                    check_resume(&link.samples, &r)?;
                    out.estimates.retain(|e| e.step < r.step);
                    let _ = ctl_tx.send(Ctl::ResendFrom(r.next_seq));
                }
                None => {
                    out.estimates.clear();
                    let _ = ctl_tx.send(Ctl::Restart);
                }
            }
            out.statuses.push(s);
        }
        Message::Status(s) => {
            *started |= s.running;
            out.statuses.push(s);
            let after_finish = link.finish_sent.load(Ordering::SeqCst);
            if *started && !s.running && !s.boot && !after_finish {
                bail!(
                    "the firmware ended the run before the recording's end: a status saying \"not running\" at filter time {:?} s, after {} estimates, with sample {} of {} being sent",
                    s.t_s,
                    out.estimates.len(),
                    link.sent_samples.load(Ordering::SeqCst),
                    link.samples.len()
                );
            }
            return Ok(after_finish && !s.running && !s.boot && s.counters.frames_rx > 0);
        }
        Message::Raw(_) | Message::Command(_) => {}
    }
    Ok(false)
}

/// A resume the recording can follow: from one of its samples, or just after its last.
fn check_resume(samples: &[RawSample], r: &protocol::Resume) -> anyhow::Result<()> {
    let known = samples.iter().any(|s| s.seq == r.next_seq)
        || samples
            .last()
            .is_none_or(|l| l.seq.wrapping_add(1) == r.next_seq);
    if known {
        return Ok(());
    }
    bail!(
        "the firmware resumed from a checkpoint at sample {} (update step {}, t = {:?} s), which the recording does not have (its samples are {}..={}): a checkpoint of another run",
        r.next_seq,
        r.step,
        r.t_s,
        samples.first().map_or(0, |s| s.seq),
        samples.last().map_or(0, |s| s.seq)
    )
}

/// Why an estimate from the firmware cannot be used, if it cannot: a time, state, 1σ,
/// innovation or NIS that is not a finite number (a 1σ or NIS below 0 neither).
pub(crate) fn estimate_problem(e: &Estimate) -> Option<String> {
    let names = ["tx_rad", "ty_rad", "tz_rad"]
        .into_iter()
        .chain(crate::simulate::COEFFICIENT_NAMES);
    if !e.t_s.is_finite() {
        return Some(format!("its time t_s = {} s is not finite", e.t_s));
    }
    if !(e.nis.is_finite() && e.nis >= 0.0) {
        return Some(format!("its NIS = {} is not a finite number >= 0", e.nis));
    }
    for ((v, s), n) in e.state.iter().zip(&e.sigma).zip(names) {
        if !v.is_finite() {
            return Some(format!("its state {n} = {v} is not finite"));
        }
        if !(s.is_finite() && *s >= 0.0) {
            return Some(format!(
                "its 1-sigma of {n} = {s} is not a finite number >= 0"
            ));
        }
    }
    if let Some(v) = e.innovation.iter().find(|v| !v.is_finite()) {
        return Some(format!("its innovation {v} m/s^2 is not finite"));
    }
    None
}

/// The firmware said the run was done: its estimates must cover the recording, one per update
/// (but for estimate frames the link lost: `lost_frames`).
/// The last estimate's time (the mean time of the last window's samples) lies within one filter
/// period of the last sample; two periods allow the last window's samples to be screened out.
fn check_complete(
    samples: &[RawSample],
    period_s: f64,
    out: &ReplayOutcome,
    lost_frames: u64,
) -> anyhow::Result<()> {
    let Some(last) = samples.last() else {
        return Ok(());
    };
    let faults = match out.faults.first() {
        Some(f) => format!(
            "; the firmware reported {} fault(s), the first: {:?} at step {}: {}",
            out.faults.len(),
            f.code,
            f.step,
            f.detail
        ),
        None => String::new(),
    };
    // Estimate frames the link lost are counted there, not the firmware's doing.
    let next = out.estimates.last().map_or(0, |e| u64::from(e.step) + 1);
    let missing = next.saturating_sub(out.estimates.len() as u64);
    if missing > lost_frames {
        bail!(
            "the firmware said the run was done, but {missing} of its {next} update steps sent no estimate (the link lost {lost_frames} frames){faults}"
        );
    }
    let covered = out.estimates.last().map(|e| e.t_s);
    if covered.is_none_or(|t| t < last.t_s - 2.0 * period_s) {
        bail!(
            "the firmware said the run was done after {} estimates{}, but the recording goes on to t = {:?} s ({} samples): its end has no estimate{faults}",
            out.estimates.len(),
            covered.map(|t| format!(" (the last at t = {t:?} s)")).unwrap_or_default(),
            last.t_s,
            samples.len()
        );
    }
    Ok(())
}

/// Reader → writer control.
enum Ctl {
    /// The firmware resumed from a checkpoint: send samples again from the one with this `seq`.
    ResendFrom(u32),
    /// The firmware rebooted without a checkpoint: configure, start and send everything again.
    Restart,
    /// The run ended (`true`) or failed; send `Shutdown` if asked, and stop.
    Done(bool),
}
