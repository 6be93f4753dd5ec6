//! `driftid record`: record the navigation computer's telemetry to a recording CSV.

use std::path::PathBuf;

use protocol::Message;

use crate::link::{self, port, record};
use crate::simulate::COEFFICIENT_NAMES;

/// Record the firmware's stream: samples to a recording CSV, raw frames to an append-only log.
#[derive(Clone, Debug, clap::Args)]
pub struct RecordArgs {
    /// Serial port of the navigation computer.
    #[arg(long)]
    pub port: String,
    /// Baud rate.
    #[arg(long, default_value_t = port::DEFAULT_BAUD, allow_hyphen_values = true, value_parser = super::args::positive_u32)]
    pub baud: u32,
    /// The recording to write (CSV interchange format).
    #[arg(long)]
    pub out: PathBuf,
    /// Also append every received byte to this raw frame log (flushed per read); an existing file
    /// that is not one is refused.
    #[arg(long)]
    pub raw: Option<PathBuf>,
    /// Latitude for the recording's metadata when the firmware does not announce one, degrees.
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::latitude_deg)]
    pub latitude_deg: Option<f64>,
    /// Stop after this many seconds (default: until interrupted).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::duration_s)]
    pub duration_s: Option<f64>,
    /// Replace a --raw file that is not a raw frame log driftid wrote (it is never appended to).
    #[arg(long)]
    pub force: bool,
    /// Exit when the port disappears instead of waiting for it to come back.
    #[arg(long)]
    pub no_reconnect: bool,
}

/// Runs `driftid record`.
pub fn run(a: &RecordArgs) -> anyhow::Result<()> {
    let opts = record::RecordOptions {
        port: a.port.clone(),
        baud: a.baud,
        out: a.out.clone(),
        raw: a.raw.clone(),
        latitude_deg: a.latitude_deg,
        duration: a
            .duration_s
            .map(|s| super::args::to_duration(s, "--duration-s"))
            .transpose()?,
        reconnect: !a.no_reconnect,
        force: a.force,
    };
    let mut samples = 0u64;
    let sum = record::record(&opts, |m| match m {
        Message::Raw(_) => {
            samples += 1;
            if samples.is_multiple_of(600) {
                eprintln!("{samples} samples received");
            }
        }
        Message::Estimate(_) | Message::Status(_) | Message::Fault(_) | Message::Hello(_) => {
            eprintln!("{}", link::describe(m))
        }
        Message::Command(_) => {}
    })?;
    eprintln!(
        "driftid record: {} samples to {}{} ({} duplicates skipped, {} sample gaps), {} estimates, {} connection(s); link: {}",
        sum.samples,
        a.out.display(),
        if sum.resumed_samples > 0 { format!(" after the {} already there", sum.resumed_samples) } else { String::new() },
        sum.duplicates,
        sum.sample_gaps,
        sum.estimates,
        sum.connections,
        sum.rx
    );
    if sum.nonfinite + sum.out_of_range + sum.temp_dropped > 0 {
        eprintln!(
            "driftid record: skipped {} non-finite and {} out-of-range samples{}; kept {} samples without their out-of-range temperature",
            sum.nonfinite,
            sum.out_of_range,
            sum.first_skipped
                .as_deref()
                .map(|s| format!(" (first: {s})"))
                .unwrap_or_default(),
            sum.temp_dropped
        );
    }
    if sum.no_temp > 0 {
        eprintln!(
            "driftid record: {} of the {} samples written have no temperature (temp_c left empty)",
            sum.no_temp, sum.samples
        );
    }
    if let Some(first) = &sum.first_bad_time {
        eprintln!(
            "driftid record: skipped {} samples with a time stamp out of line with their neighbours (first: {first})",
            sum.bad_times
        );
    }
    if let Some(u) = &sum.unconfirmed {
        eprintln!("driftid record: warning: {u}");
    }
    for n in &sum.notes {
        eprintln!("driftid record: warning: {n}");
    }
    if let Some(e) = sum.last_estimate {
        for (i, n) in COEFFICIENT_NAMES.iter().enumerate() {
            let (v, s) = (e.state[3 + i], e.sigma[3 + i]);
            eprintln!("  {n:>4} = {}", crate::format::pm(v, s));
        }
    }
    Ok(())
}
