//! Recording the firmware's stream: raw samples to a recording CSV (the interchange format, so
//! `identify`/`diagnose` take it directly), every received byte to an append-only raw log
//! (flushed per read: a killed recorder loses nothing already received), estimates and status
//! shown as they come. When the port disappears, the recorder waits for it and reconnects.
//!
//! Restarting `driftid record` on the same `--out` resumes the recording: the existing file is
//! checked, a partial last line (a recorder killed mid-write) is cut off and reported, and only
//! samples later than its last one are appended. Sample identity is the time `t_s` (the CSV has
//! no sequence column; times strictly increase), so samples the firmware sends again after a
//! reconnect or a reset are skipped, never duplicated. A file recorded at another latitude than
//! the firmware reports is refused, not mixed.

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context as _;
use protocol::{Command, Encoder, Estimate, Hello, Message};

use super::port::{self, is_gone, is_timeout};
use super::{LinkStats, Receiver};
use crate::recording::{
    check_gravity_mps2, check_latitude_deg, sample_problem, Metadata, RawSample, RecordingWriter,
};

/// Opens the link for one connection; `Ok(None)`: no more connections (tests).
pub type Opener<'a, P> = dyn FnMut() -> anyhow::Result<Option<P>> + 'a;

/// How to record.
#[derive(Clone, Debug)]
pub struct RecordOptions {
    /// Serial port path.
    pub port: String,
    /// Baud rate.
    pub baud: u32,
    /// Recording CSV to write.
    pub out: PathBuf,
    /// Append-only raw frame log.
    pub raw: Option<PathBuf>,
    /// Latitude for the CSV metadata if the firmware's Hello does not arrive first.
    pub latitude_deg: Option<f64>,
    /// Stop after this long (None: until interrupted or the port is gone for good).
    pub duration: Option<Duration>,
    /// Keep waiting for the port when it disappears.
    pub reconnect: bool,
    /// Replace a `raw` file that is not a raw frame log (else it is refused).
    pub force: bool,
}

/// What was recorded.
#[derive(Clone, Debug, Default)]
pub struct RecordSummary {
    /// Samples written to the CSV.
    pub samples: u64,
    /// Samples skipped as duplicates (time not after the last written, e.g. after a reconnect).
    pub duplicates: u64,
    /// Gaps in the firmware's sample numbers (samples it did not send or we did not receive).
    pub sample_gaps: u64,
    /// Estimates received.
    pub estimates: u64,
    /// The latest estimate.
    pub last_estimate: Option<Estimate>,
    /// The firmware's identification.
    pub hello: Option<Hello>,
    /// Link loss accounting over all connections.
    pub rx: LinkStats,
    /// Times the port was (re)opened.
    pub connections: u64,
    /// Samples already in the file when the recorder started (resumed recording).
    pub resumed_samples: u64,
    /// Repairs made to the existing file before appending (a partial last line).
    pub repairs: Vec<String>,
    /// Samples skipped because a value was NaN or infinite (the reader refuses them).
    pub nonfinite: u64,
    /// Samples skipped because a value was out of the reader's range (|a| too large).
    pub out_of_range: u64,
    /// Samples kept without their temperature, which was outside the reader's range.
    pub temp_dropped: u64,
    /// The first skipped sample and why (for the summary).
    pub first_skipped: Option<String>,
    /// Metadata the firmware announced that the recording format refuses, left out of the file.
    pub notes: Vec<String>,
}

struct Sink {
    csv: Option<RecordingWriter<BufWriter<File>>>,
    raw: Option<File>,
    last_t: Option<f64>,
    last_seq: Option<u32>,
    /// Metadata of the file being appended to (checked against the firmware's Hello).
    file_meta: Option<Metadata>,
}

/// Opens `path` to go on recording into it, if it exists and is not empty.
fn resume(path: &Path, sink: &mut Sink, sum: &mut RecordSummary) -> anyhow::Result<()> {
    match std::fs::metadata(path) {
        Ok(m) if m.len() > 0 => {}
        _ => return Ok(()),
    }
    let a = RecordingWriter::append(path).with_context(|| {
        format!(
            "{} exists but cannot be appended to; record to another file",
            path.display()
        )
    })?;
    if let Some(r) = &a.repair {
        eprintln!("driftid record: {r}");
        sum.repairs.push(r.clone());
    }
    eprintln!(
        "driftid record: resuming {}: {} samples already recorded{}",
        path.display(),
        a.samples,
        a.last_t_s
            .map(|t| format!(", the last at t = {t} s; later samples are appended"))
            .unwrap_or_default()
    );
    sum.resumed_samples = a.samples;
    sink.last_t = a.last_t_s;
    sink.file_meta = Some(a.meta);
    sink.csv = Some(a.writer);
    Ok(())
}

/// Records until the duration ends or the port is gone (and `reconnect` is off).
pub fn record(opts: &RecordOptions, on_msg: impl FnMut(&Message)) -> anyhow::Result<RecordSummary> {
    let mut first = true;
    let t0 = Instant::now();
    let mut open = || -> anyhow::Result<Option<serialport::TTYPort>> {
        loop {
            match port::open(&opts.port, opts.baud) {
                Ok(p) => {
                    first = false;
                    return Ok(Some(p));
                }
                // Waiting for the port to come back.
                Err(_) if opts.reconnect && !first => {
                    if opts.duration.is_some_and(|d| t0.elapsed() >= d) {
                        return Ok(None);
                    }
                    std::thread::sleep(Duration::from_millis(500));
                }
                Err(e) => return Err(e),
            }
        }
    };
    record_with(opts, &mut open, on_msg)
}

/// [`record`] over any link: `open` gives each connection (a serial port, or a test double).
pub fn record_with<P: Read + Write>(
    opts: &RecordOptions,
    open: &mut Opener<'_, P>,
    mut on_msg: impl FnMut(&Message),
) -> anyhow::Result<RecordSummary> {
    let start = Instant::now();
    let expired = || opts.duration.is_some_and(|d| start.elapsed() >= d);
    if let Some(raw) = &opts.raw {
        crate::output::ensure_not_input(raw, "--raw", &[&opts.out])?;
    }
    // Appended to only when it is a raw frame log already (or empty): never a recording or
    // another file of the user's, unless --force (which replaces it).
    let raw = match &opts.raw {
        Some(p) => Some(crate::output::open_log(p, "--raw", opts.force)?),
        None => None,
    };
    let mut sink = Sink {
        csv: None,
        raw,
        last_t: None,
        last_seq: None,
        file_meta: None,
    };
    let mut sum = RecordSummary::default();
    resume(&opts.out, &mut sink, &mut sum)?;
    // One receiver across connections: a frame cut off by a disconnect is ended by the next
    // connection's first delimiter and counted as damaged, not forgotten.
    let mut rx = Receiver::new();
    while !expired() {
        let Some(mut port) = open()? else { break };
        sum.connections += 1;
        // Ask for Hello + Status (metadata for the CSV, and a sign of life).
        let mut enc = Encoder::new();
        if let Ok(f) = enc.frame(Message::Command(Command::Ping)) {
            let _ = port.write_all(f);
        }
        let mut buf = [0u8; 4096];
        let gone = loop {
            if expired() {
                break false;
            }
            let n = match port.read(&mut buf) {
                Ok(0) => continue,
                Ok(n) => n,
                Err(e) if is_timeout(&e) => continue,
                Err(e) if is_gone(&e) => break true,
                Err(e) => return Err(e).context("reading from the link"),
            };
            if let Some(r) = sink.raw.as_mut() {
                r.write_all(&buf[..n]).context("writing the raw log")?;
                r.flush().context("flushing the raw log")?;
            }
            for p in rx.feed(&buf[..n]) {
                on_msg(&p.msg);
                handle(opts, &mut sink, &mut sum, p.msg)?;
            }
            if let Some(w) = sink.csv.as_mut() {
                w.flush().context("flushing the recording")?;
            }
        };
        sum.rx = rx.stats();
        if !gone || !opts.reconnect {
            break;
        }
        eprintln!(
            "driftid record: {} disappeared; waiting for it to come back",
            opts.port
        );
    }
    if let Some(w) = sink.csv.as_mut() {
        w.flush()?;
    }
    Ok(sum)
}

fn handle(
    opts: &RecordOptions,
    sink: &mut Sink,
    sum: &mut RecordSummary,
    msg: Message,
) -> anyhow::Result<()> {
    match msg {
        Message::Hello(h) => {
            if let Some(lat) = sink.file_meta.as_ref().and_then(|m| m.latitude_deg) {
                // Written so that a NaN from the firmware is a mismatch too.
                let same = (lat - h.config.latitude_deg).abs() <= 1e-9;
                if !same {
                    anyhow::bail!(
                        "{}: recorded at latitude {lat} deg, but the firmware reports {} deg: refusing to mix two runs in one recording; record to another file",
                        opts.out.display(),
                        h.config.latitude_deg
                    );
                }
            }
            sum.hello = Some(h)
        }
        Message::Estimate(e) => {
            sum.estimates += 1;
            sum.last_estimate = Some(e);
        }
        Message::Raw(r) => {
            if sink.last_t.is_some_and(|t| r.t_s <= t) {
                sum.duplicates += 1;
                return Ok(());
            }
            if let Some(prev) = sink.last_seq {
                if r.seq > prev.wrapping_add(1) {
                    sum.sample_gaps += u64::from(r.seq.wrapping_sub(prev).wrapping_sub(1));
                }
            }
            sink.last_seq = Some(r.seq);
            // Only what the reader accepts is written (its own rules, `sample_problem`): a bad
            // sample is skipped and counted, and recording goes on.
            let mut sample = RawSample {
                t_s: r.t_s,
                specific_force_mps2: r.specific_force,
                temp_c: None,
            };
            if let Some(problem) = sample_problem(&sample) {
                let finite = r.t_s.is_finite() && r.specific_force.iter().all(|v| v.is_finite());
                if finite {
                    sum.out_of_range += 1;
                } else {
                    sum.nonfinite += 1;
                }
                if sum.first_skipped.is_none() {
                    sum.first_skipped = Some(format!("sample {}: {problem}", r.seq));
                }
                return Ok(());
            }
            // NaN is the firmware's "no temperature"; an implausible one is dropped, counted.
            if r.temp_c.is_finite() {
                sample.temp_c = Some(r.temp_c);
                if sample_problem(&sample).is_some() {
                    sample.temp_c = None;
                    sum.temp_dropped += 1;
                }
            }
            if sink.csv.is_none() {
                let meta = new_metadata(opts, sum);
                let w = RecordingWriter::create(&opts.out, &meta, r.temp_c.is_finite())
                    .with_context(|| format!("creating {}", opts.out.display()))?;
                sink.csv = Some(w);
            }
            let Some(w) = sink.csv.as_mut() else {
                anyhow::bail!("internal error: no recording writer");
            };
            w.write_sample(&sample).context("writing the recording")?;
            sink.last_t = Some(r.t_s);
            sum.samples += 1;
        }
        Message::Status(_) | Message::Fault(_) | Message::Command(_) => {}
    }
    Ok(())
}

/// The metadata of a new recording: latitude and gravity from the firmware's Hello (latitude
/// from `--latitude-deg` when no Hello came first), each checked by the reader's own rules; a
/// value the reader would refuse is left out (the reader then asks for `--latitude-deg`, or uses
/// normal gravity) and said in [`RecordSummary::notes`].
fn new_metadata(opts: &RecordOptions, sum: &mut RecordSummary) -> Metadata {
    let hello = sum.hello;
    let mut keep =
        |what: &str, from: &str, v: Option<f64>, check: fn(f64) -> Result<f64, String>| {
            v.and_then(|v| match check(v) {
                Ok(v) => Some(v),
                Err(e) => {
                    sum.notes.push(format!(
                        "{}: {from} {what} {e}; left out of the recording's metadata",
                        opts.out.display()
                    ));
                    None
                }
            })
        };
    let latitude_deg = match hello {
        Some(h) => keep(
            "latitude_deg",
            "the firmware's",
            Some(h.config.latitude_deg),
            check_latitude_deg,
        ),
        None => None,
    }
    .or_else(|| {
        keep(
            "latitude_deg",
            "the given",
            opts.latitude_deg,
            check_latitude_deg,
        )
    });
    let gravity_mps2 = keep(
        "gravity_mps2",
        "the firmware's",
        hello.and_then(|h| h.config.gravity_mps2),
        check_gravity_mps2,
    );
    Metadata {
        latitude_deg,
        gravity_mps2,
        description: Some(format!("driftid record from {}", opts.port)),
        extra: Vec::new(),
    }
}
