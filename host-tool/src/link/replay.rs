//! Hardware-in-the-loop replay: stream a recording into the firmware over the link and collect
//! what comes back.
//!
//! A writer thread sends `Configure`, `Start(Replay)`, one `Replay` frame per sample, `Finish`
//! (one `write_all` per frame); the calling thread reads concurrently (the firmware blocks on
//! output while the host does not read, so reading and writing must overlap). The run ends at the
//! first `Status` saying "not running" after `Finish` went out; then, if asked, `Shutdown`.
//!
//! Resets: when the firmware reboots during the run (a boot `Status`), the replay goes on from
//! where the firmware can: from the checkpoint's sample (`Status::resumed.next_seq`), or from the
//! start (`Configure`, `Start`) when it had no checkpoint. Estimates the resumed firmware will
//! send again (step ≥ the checkpoint's) are dropped from the outcome, so it holds each update
//! once, as the uninterrupted run would.

use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _};
use protocol::{
    Command, Config, Encoder, Estimate, Fault, Hello, Message, RawSample, Source, Status,
};

use super::port::{is_gone, is_timeout};
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
}

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            config: Config::default(),
            shutdown: false,
            timeout: Duration::from_secs(600),
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
pub fn replay<R: Read, W: Write + Send>(
    mut reader: R,
    writer: W,
    samples: &[RawSample],
    opts: &ReplayOptions,
    mut alive: impl FnMut() -> bool,
    mut on_bytes: impl FnMut(&[u8]) -> anyhow::Result<()>,
    mut on_msg: impl FnMut(&Message),
) -> anyhow::Result<ReplayOutcome> {
    let start = Instant::now();
    let deadline = start + opts.timeout;
    let finish_sent = AtomicBool::new(false);
    let (ctl_tx, ctl_rx) = mpsc::channel::<Ctl>();
    let sent_frames = AtomicU64::new(0);
    let mut out = ReplayOutcome::default();
    let mut rx = Receiver::new();
    let config = opts.config;
    let shutdown = opts.shutdown;

    let (result, sent) = std::thread::scope(|scope| {
        let finish_flag = &finish_sent;
        let sent_count = &sent_frames;
        let writer_thread = scope.spawn(move || -> anyhow::Result<u64> {
            let mut w = writer;
            let mut enc = Encoder::new();
            let mut send = |w: &mut W, cmd: Command| -> anyhow::Result<()> {
                let f = enc
                    .frame(Message::Command(cmd))
                    .map_err(|e| anyhow::anyhow!("{e}"))?;
                sent_count.fetch_add(1, Ordering::SeqCst);
                w.write_all(f).context("writing to the link")
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
                        if ok && shutdown {
                            send(&mut w, Command::Shutdown)?;
                            w.flush().context("flushing the link")?;
                        }
                        break;
                    }
                    Some(Ctl::ResendFrom(seq)) => {
                        finish_flag.store(false, Ordering::SeqCst);
                        i = samples
                            .iter()
                            .position(|s| s.seq == seq)
                            .unwrap_or(samples.len());
                        continue;
                    }
                    Some(Ctl::Restart) => {
                        finish_flag.store(false, Ordering::SeqCst);
                        send(&mut w, Command::Configure(config))?;
                        send(&mut w, Command::Start(Source::Replay))?;
                        i = 0;
                        continue;
                    }
                    None => {}
                }
                if i < samples.len() {
                    send(&mut w, Command::Replay(samples[i]))?;
                } else {
                    send(&mut w, Command::Finish)?;
                    w.flush().context("flushing the link")?;
                    finish_flag.store(true, Ordering::SeqCst);
                }
                i += 1;
            }
            Ok(sent_count.load(Ordering::SeqCst))
        });

        let result = (|| -> anyhow::Result<()> {
            let mut buf = [0u8; 4096];
            let mut started = false;
            loop {
                if Instant::now() > deadline {
                    bail!(
                        "replay timed out after {:?} ({} estimates received)",
                        opts.timeout,
                        out.estimates.len()
                    );
                }
                let n = match reader.read(&mut buf) {
                    Ok(0) => {
                        if !alive() {
                            bail!("the firmware ended before the replay finished");
                        }
                        continue;
                    }
                    Ok(n) => n,
                    Err(e) if is_timeout(&e) => {
                        if !alive() {
                            bail!("the firmware ended before the replay finished");
                        }
                        continue;
                    }
                    Err(e) if is_gone(&e) => bail!("the link went away: {e}"),
                    Err(e) => return Err(e).context("reading from the link"),
                };
                on_bytes(&buf[..n])?;
                let mut end = false;
                for p in rx.feed(&buf[..n]) {
                    on_msg(&p.msg);
                    match p.msg {
                        Message::Hello(h) => out.hello = Some(h),
                        Message::Estimate(e) => out.estimates.push(e),
                        Message::Fault(f) => out.faults.push(f),
                        Message::Status(s) if s.boot && started => {
                            // The firmware rebooted mid-run: go on from its checkpoint, or restart.
                            out.resets.push(s.resumed);
                            match s.resumed {
                                Some(r) => {
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
                            started |= s.running;
                            let after_finish = finish_sent.load(Ordering::SeqCst);
                            if after_finish && !s.running && !s.boot && s.counters.frames_rx > 0 {
                                end = true;
                            }
                            out.statuses.push(s);
                        }
                        Message::Raw(_) | Message::Command(_) => {}
                    }
                }
                if end {
                    return Ok(());
                }
            }
        })();
        let _ = ctl_tx.send(Ctl::Done(result.is_ok()));
        let sent = writer_thread
            .join()
            .map_err(|_| anyhow::anyhow!("the writer thread panicked"));
        (result, sent)
    });
    result?;
    out.frames_sent = sent??;
    out.rx = rx.stats();
    out.elapsed_s = start.elapsed().as_secs_f64();
    Ok(out)
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
