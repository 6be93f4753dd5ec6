//! Recording the firmware's stream: raw samples to a recording CSV (the interchange format, so
//! `identify`/`diagnose` take it directly), every received byte to an append-only raw log
//! (flushed per read: a killed recorder loses nothing already received), estimates and status
//! shown as they come. When the port disappears, the recorder waits for it and reconnects.
//!
//! Restarting `driftid record` on the same `--out` resumes the recording: the existing file is
//! checked, a partial last line (a recorder killed mid-write) is cut off and reported, and only
//! samples later than its last one are appended. Sample identity is the time `t_s` (the CSV has
//! no sequence column; times strictly increase): samples the firmware sends again after a
//! reconnect, or the overlap of a run it resumes from a checkpoint, are skipped, never
//! duplicated ([`super::timeline`]). Another run is never mixed in: a firmware whose clock
//! restarts, or which reports another latitude than the recording's, stops the recorder with an
//! error naming the sample (the file keeps the first run). A time stamp out of line with its
//! neighbours is skipped by name. Every recording has a `temp_c` column (empty where a sample
//! has no temperature, counted). Receiving no sample at all is an error (exit 2), and then no
//! file is made: neither the recording nor the `--raw` log (created at the first byte).

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context as _;
use protocol::{Command, Encoder, Estimate, Hello, Message, SeqEvent, SeqTracker};

use super::port::{self, is_gone, is_timeout};
use super::timeline::{Timeline, Verdict};
use super::{LinkStats, Receiver};
use crate::output::{check_output, Made};
use crate::recording::{
    check_gravity_mps2, check_latitude_deg, sample_problem, Metadata, RawSample, RecordingWriter,
};

/// Opens the link for one connection; `Ok(None)`: no more connections (tests).
pub(crate) type Opener<'a, P> = dyn FnMut() -> anyhow::Result<Option<P>> + 'a;

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
    /// Samples skipped as already recorded (resent after a reconnect or to a restarted
    /// recorder, or a run resumed from a checkpoint overlapping the recording).
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
    /// Samples written without a temperature (none sent, or a resumed file has no `temp_c`).
    pub no_temp: u64,
    /// Samples skipped for a time stamp out of line with their neighbours.
    pub bad_times: u64,
    /// The first of those, named.
    pub first_bad_time: Option<String>,
    /// A sample held at the end to check its jump ahead, never confirmed: not written.
    pub unconfirmed: Option<String>,
    /// The first skipped sample and why (for the summary).
    pub first_skipped: Option<String>,
    /// Metadata the firmware announced that the recording format refuses, left out of the file.
    pub notes: Vec<String>,
}

struct Sink {
    csv: Option<RecordingWriter<BufWriter<File>>>,
    /// The raw log, opened at the first byte received (nothing received: no file).
    raw: Option<File>,
    timeline: Timeline,
    last_seq: Option<u32>,
    /// Latitude of the run in the file, deg (the file's, or the firmware's when it was made).
    run_lat: Option<f64>,
    /// The firmware's link sequence numbers: starting again at 0 is a reboot.
    link_seq: SeqTracker,
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
    sink.run_lat = a.meta.latitude_deg;
    sink.csv = Some(a.writer);
    remember_recorded(path, &mut sink.timeline)
}

/// Gives `timeline` the samples already in the file (the last [`super::timeline::RECENT`]
/// are kept), so a resend of one is recognised.
fn remember_recorded(path: &Path, timeline: &mut Timeline) -> anyhow::Result<()> {
    let f = File::open(path).with_context(|| format!("opening {}", path.display()))?;
    let reader = crate::recording::RecordingReader::new(
        std::io::BufReader::new(f),
        path.display().to_string(),
    )?;
    for item in reader {
        let (_, s) = item?;
        timeline.written(&protocol::RawSample {
            seq: 0,
            t_s: s.t_s,
            specific_force: s.specific_force_mps2,
            temp_c: f64::NAN,
        });
    }
    Ok(())
}

/// Records until the duration ends or the port is gone (and `reconnect` is off).
pub(crate) fn record(
    opts: &RecordOptions,
    on_msg: impl FnMut(&Message),
) -> anyhow::Result<RecordSummary> {
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
    // Appended to only when it is a raw frame log already (or empty): never a recording or
    // another file of the user's, unless --force (which replaces it). Checked now, opened at the
    // first byte received.
    if let Some(raw) = &opts.raw {
        crate::output::ensure_not_input(raw, "--raw", &[&opts.out])?;
        check_output(raw, "--raw", &Made::RawLog, opts.force)?;
    }
    let mut sink = Sink {
        csv: None,
        raw: None,
        timeline: Timeline::new(),
        last_seq: None,
        run_lat: None,
        link_seq: SeqTracker::new(),
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
            take_bytes(opts, &mut sink, &mut sum, &mut rx, &buf[..n], &mut on_msg)?;
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
    if let Some(h) = sink.timeline.unconfirmed() {
        sum.unconfirmed = Some(format!(
            "sample {}: t_s = {:?} s is out of line with the last sample recorded (t_s = {:?} s) and no later sample came to tell a gap or a new run from a bad time stamp; not written",
            h.seq,
            h.t_s,
            sink.timeline.last_t().unwrap_or(f64::NAN)
        ));
    }
    if sum.samples == 0 {
        anyhow::bail!("{}", nothing_recorded(opts, &sum, start.elapsed()));
    }
    Ok(sum)
}

/// Takes bytes received: logged raw, decoded, each message handled; the rows flushed.
fn take_bytes(
    opts: &RecordOptions,
    sink: &mut Sink,
    sum: &mut RecordSummary,
    rx: &mut Receiver,
    bytes: &[u8],
    on_msg: &mut impl FnMut(&Message),
) -> anyhow::Result<()> {
    log_raw(opts, sink, bytes)?;
    for p in rx.feed(bytes) {
        on_msg(&p.msg);
        if sink.link_seq.observe(p.seq) == SeqEvent::Restart && p.seq == 0 {
            // The firmware rebooted; its boot status may still say it resumed.
            sink.timeline.firmware_reset(false);
        }
        handle(opts, sink, sum, p.msg)?;
    }
    if let Some(w) = sink.csv.as_mut() {
        w.flush().context("flushing the recording")?;
    }
    Ok(())
}

/// Appends received bytes to the raw log, creating it at the first.
fn log_raw(opts: &RecordOptions, sink: &mut Sink, bytes: &[u8]) -> anyhow::Result<()> {
    let Some(path) = &opts.raw else {
        return Ok(());
    };
    if sink.raw.is_none() {
        sink.raw = Some(crate::output::open_log(path, "--raw", opts.force)?);
    }
    if let Some(r) = sink.raw.as_mut() {
        r.write_all(bytes).context("writing the raw log")?;
        r.flush().context("flushing the raw log")?;
    }
    Ok(())
}

/// Why a recording got no sample, from what did arrive.
fn nothing_recorded(opts: &RecordOptions, sum: &RecordSummary, took: Duration) -> String {
    let d = &sum.rx.decoder;
    let what = if d.bytes == 0 {
        format!(
            "nothing received from {} in {:.1} s",
            opts.port,
            took.as_secs_f64()
        )
    } else if d.ok == 0 {
        format!(
            "{} bytes received from {} but no valid frame (another baud rate, or not the firmware?)",
            d.bytes, opts.port
        )
    } else if sum.duplicates + sum.nonfinite + sum.out_of_range + sum.bad_times > 0 {
        format!(
            "no new sample: {} already recorded, {} non-finite, {} out of range, {} with a bad time stamp",
            sum.duplicates, sum.nonfinite, sum.out_of_range, sum.bad_times
        )
    } else {
        format!(
            "{} frames received from {} but no sample (is the firmware running in sensor mode, with echo_raw on?)",
            d.ok, opts.port
        )
    };
    let file = if sum.resumed_samples > 0 {
        "left as it was"
    } else {
        "not written"
    };
    format!(
        "{what}: no sample recorded, {} {file}{}",
        opts.out.display(),
        if sum.connections > 0 {
            format!("; link: {}", sum.rx)
        } else {
            String::new()
        }
    )
}

fn handle(
    opts: &RecordOptions,
    sink: &mut Sink,
    sum: &mut RecordSummary,
    msg: Message,
) -> anyhow::Result<()> {
    match msg {
        Message::Hello(h) => {
            let lat = h.config.latitude_deg;
            if let Some(run) = sink.run_lat {
                // Written so that a NaN from the firmware is a mismatch too.
                let same = (run - lat).abs() <= 1e-9 || run.to_bits() == lat.to_bits();
                if !same {
                    anyhow::bail!(
                        "{}: recorded at latitude {run} deg, but the firmware reports {lat} deg: another run; {}",
                        opts.out.display(),
                        not_mixed(opts, sink, sum)
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
            count_gap(sink, sum, r.seq);
            if let Some(problem) = sample_problem(&to_sample(&r, None)) {
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
            for v in sink.timeline.push(&r) {
                match v {
                    Verdict::Write(w) => write_sample(opts, sink, sum, &w)?,
                    Verdict::Resent => sum.duplicates += 1,
                    Verdict::Held => {}
                    Verdict::Absurd(why) => {
                        sum.bad_times += 1;
                        sum.first_bad_time.get_or_insert(why);
                    }
                    Verdict::NewRun(why) => anyhow::bail!(
                        "{}: {why}; {}",
                        opts.out.display(),
                        not_mixed(opts, sink, sum)
                    ),
                }
            }
        }
        Message::Status(s) if s.boot => sink.timeline.firmware_reset(s.resumed.is_some()),
        Message::Status(_) | Message::Fault(_) | Message::Command(_) => {}
    }
    Ok(())
}

/// Counts samples the firmware numbered but did not send (or we did not receive); numbers
/// going back (a resend) are not gaps.
fn count_gap(sink: &mut Sink, sum: &mut RecordSummary, seq: u32) {
    if let Some(prev) = sink.last_seq {
        if seq <= prev {
            return;
        }
        sum.sample_gaps += u64::from(seq - prev - 1);
    }
    sink.last_seq = Some(seq);
}

/// The end of an error about another run: what the file keeps.
fn not_mixed(opts: &RecordOptions, sink: &Sink, sum: &RecordSummary) -> String {
    let kept = match sink.timeline.last_t() {
        Some(t) => format!(
            "{} keeps the first run ({} samples, up to t_s = {t:?} s)",
            opts.out.display(),
            sum.resumed_samples + sum.samples
        ),
        None => format!("{} was not written", opts.out.display()),
    };
    format!("refusing to mix two runs in one recording: {kept}; record the new run to another file")
}

fn to_sample(r: &protocol::RawSample, temp_c: Option<f64>) -> RawSample {
    RawSample {
        t_s: r.t_s,
        specific_force_mps2: r.specific_force,
        temp_c,
    }
}

/// Writes one sample that continues the recording (creating the file at the first).
fn write_sample(
    opts: &RecordOptions,
    sink: &mut Sink,
    sum: &mut RecordSummary,
    r: &protocol::RawSample,
) -> anyhow::Result<()> {
    // NaN is the firmware's "no temperature"; an implausible one is dropped, counted.
    let mut sample = to_sample(r, None);
    if r.temp_c.is_finite() {
        sample.temp_c = Some(r.temp_c);
        if sample_problem(&sample).is_some() {
            sample.temp_c = None;
            sum.temp_dropped += 1;
        }
    }
    if sink.csv.is_none() {
        // Always with a temp_c column: a first sample without a temperature does not decide
        // for the whole recording.
        let meta = new_metadata(opts, sum);
        sink.run_lat = meta
            .latitude_deg
            .or(sum.hello.map(|h| h.config.latitude_deg));
        let w = RecordingWriter::create(&opts.out, &meta, true)
            .with_context(|| format!("creating {}", opts.out.display()))?;
        sink.csv = Some(w);
    }
    let Some(w) = sink.csv.as_mut() else {
        anyhow::bail!("internal error: no recording writer");
    };
    if sample.temp_c.is_none() || !w.has_temp() {
        sum.no_temp += 1;
    }
    w.write_sample(&sample).context("writing the recording")?;
    sum.samples += 1;
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
