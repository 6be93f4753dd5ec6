//! Recording the firmware's stream: raw samples to a recording CSV (the interchange format, so
//! `identify`/`diagnose` take it directly), every received byte to an append-only raw log
//! (flushed per read: a killed recorder loses nothing already received), estimates and status
//! shown as they come. When the port disappears, the recorder waits for it and reconnects.

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Read, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use protocol::{Command, Encoder, Estimate, Hello, Message};

use super::port::{self, is_gone, is_timeout};
use super::{LinkStats, Receiver};
use crate::recording::{Metadata, RawSample, RecordingWriter};

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
    /// Link loss accounting, summed over connections.
    pub rx: LinkStats,
    /// Times the port was (re)opened.
    pub connections: u64,
}

struct Sink {
    csv: Option<RecordingWriter<BufWriter<File>>>,
    raw: Option<File>,
    last_t: Option<f64>,
    last_seq: Option<u32>,
}

/// Records until the duration ends or the port is gone (and `reconnect` is off).
pub fn record(opts: &RecordOptions, mut on_msg: impl FnMut(&Message)) -> anyhow::Result<RecordSummary> {
    let start = Instant::now();
    let expired = || opts.duration.is_some_and(|d| start.elapsed() >= d);
    let raw = match &opts.raw {
        Some(p) => Some(
            OpenOptions::new().create(true).append(true).open(p).with_context(|| format!("opening {}", p.display()))?,
        ),
        None => None,
    };
    let mut sink = Sink { csv: None, raw, last_t: None, last_seq: None };
    let mut sum = RecordSummary::default();
    while !expired() {
        let mut port = match port::open(&opts.port, opts.baud) {
            Ok(p) => p,
            Err(e) if opts.reconnect && sum.connections > 0 => {
                let _ = e;
                std::thread::sleep(Duration::from_millis(500));
                continue;
            }
            Err(e) => return Err(e),
        };
        sum.connections += 1;
        // Ask for Hello + Status (metadata for the CSV, and a sign of life).
        let mut enc = Encoder::new();
        if let Ok(f) = enc.frame(Message::Command(Command::Ping)) {
            let _ = port.write_all(f);
        }
        let mut rx = Receiver::new();
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
        let s = rx.stats();
        sum.rx.decoder.ok += s.decoder.ok;
        sum.rx.decoder.crc += s.decoder.crc;
        sum.rx.decoder.cobs += s.decoder.cobs;
        sum.rx.decoder.overflow += s.decoder.overflow;
        sum.rx.decoder.version += s.decoder.version;
        sum.rx.decoder.malformed += s.decoder.malformed;
        sum.rx.decoder.bytes += s.decoder.bytes;
        sum.rx.missing += s.missing;
        sum.rx.restarts += s.restarts;
        if !gone || !opts.reconnect {
            break;
        }
        eprintln!("driftid record: {} disappeared; waiting for it to come back", opts.port);
    }
    if let Some(w) = sink.csv.as_mut() {
        w.flush()?;
    }
    Ok(sum)
}

fn handle(opts: &RecordOptions, sink: &mut Sink, sum: &mut RecordSummary, msg: Message) -> anyhow::Result<()> {
    match msg {
        Message::Hello(h) => sum.hello = Some(h),
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
                    sum.sample_gaps += u64::from(r.seq - prev - 1);
                }
            }
            if sink.csv.is_none() {
                let latitude_deg = sum.hello.map(|h| h.config.latitude_deg).or(opts.latitude_deg);
                let meta = Metadata {
                    latitude_deg,
                    gravity_mps2: sum.hello.and_then(|h| h.config.gravity_mps2),
                    description: Some(format!("driftid record from {}", opts.port)),
                    extra: Vec::new(),
                };
                let w = RecordingWriter::create(&opts.out, &meta, r.temp_c.is_finite())
                    .with_context(|| format!("creating {}", opts.out.display()))?;
                sink.csv = Some(w);
            }
            let w = sink.csv.as_mut().expect("created above");
            w.write_sample(&RawSample {
                t_s: r.t_s,
                specific_force_mps2: r.specific_force,
                temp_c: r.temp_c.is_finite().then_some(r.temp_c),
            })
            .context("writing the recording")?;
            sink.last_t = Some(r.t_s);
            sink.last_seq = Some(r.seq);
            sum.samples += 1;
        }
        Message::Status(_) | Message::Fault(_) | Message::Command(_) => {}
    }
    Ok(())
}
