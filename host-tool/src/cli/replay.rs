//! `driftid replay`: stream a recording into the firmware (hardware-in-the-loop replay) and
//! record what comes back.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context as _;
use protocol::{Config, Estimate};

use crate::link::{self, port, replay};
use crate::output::{self, AtomicFile};
use crate::recording;
use crate::simulate::COEFFICIENT_NAMES;

/// Replay a recording into the firmware over a serial port; write the estimates it returns.
#[derive(Clone, Debug, clap::Args)]
pub struct ReplayArgs {
    /// The recording (CSV interchange format).
    pub recording: PathBuf,
    /// Serial port of the navigation computer (or QEMU's pty).
    #[arg(long)]
    pub port: String,
    /// Baud rate.
    #[arg(long, default_value_t = port::DEFAULT_BAUD, allow_hyphen_values = true, value_parser = super::args::positive_u32)]
    pub baud: u32,
    /// Filter period, s.
    #[arg(long, default_value_t = 60.0, allow_hyphen_values = true, value_parser = super::args::period_s)]
    pub period_s: f64,
    /// 1σ noise of one raw sample, m/s² (default: 1e-5 g per 60-s mean at the recording's rate).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::raw_sigma)]
    pub raw_sigma: Option<f64>,
    /// Gyro angle random walk, deg²/h.
    #[arg(long, default_value_t = 1e-8, allow_hyphen_values = true, value_parser = super::args::arw)]
    pub arw: f64,
    /// χ² innovation gate of the firmware's filter (NIS threshold; 0: off). Rejections are
    /// counted in the status; 10 in a row raise a fault.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = super::args::gate_nis)]
    pub gate_nis: f64,
    /// Where to write the firmware's estimates (CSV); default: RECORDING.firmware.csv.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Append every byte received to this raw frame log.
    #[arg(long)]
    pub raw: Option<PathBuf>,
    /// Replace an existing --out that is not an estimates file driftid wrote, or a --raw that
    /// is not a raw frame log (else such a file is refused).
    #[arg(long)]
    pub force: bool,
    /// Send Shutdown at the end (QEMU exits; a real board resets).
    #[arg(long)]
    pub shutdown: bool,
    /// Give up after this many seconds (writing to a firmware that does not read included).
    #[arg(long, default_value_t = 3600.0, allow_hyphen_values = true, value_parser = super::args::duration_s)]
    pub timeout_s: f64,
    /// Give up when the firmware sends nothing for this many seconds (it stopped answering).
    #[arg(long, default_value_t = 60.0, allow_hyphen_values = true, value_parser = super::args::duration_s)]
    pub silence_s: f64,
    /// Print every estimate.
    #[arg(long)]
    pub verbose: bool,
}

/// Estimates CSV header: step, time, samples, NIS, innovation, 15 states, 15 sigmas.
pub(crate) fn estimates_header() -> String {
    let names: Vec<String> = ["tx_rad", "ty_rad", "tz_rad"]
        .iter()
        .map(|s| s.to_string())
        .chain(COEFFICIENT_NAMES.iter().map(|s| s.to_string()))
        .collect();
    let mut h = String::from("step,t_s,samples,nis,innov_x_mps2,innov_y_mps2,innov_z_mps2");
    for n in &names {
        h.push(',');
        h.push_str(n);
    }
    for n in &names {
        h.push_str(",sigma_");
        h.push_str(n);
    }
    h
}

/// One estimates CSV row (shortest round-trip float formatting: exact).
pub(crate) fn estimate_row(e: &Estimate) -> String {
    let mut r = format!(
        "{},{:?},{},{:?},{:?},{:?},{:?}",
        e.step, e.t_s, e.samples, e.nis, e.innovation[0], e.innovation[1], e.innovation[2]
    );
    for v in e.state.iter().chain(e.sigma.iter()) {
        r.push_str(&format!(",{v:?}"));
    }
    r
}

/// Runs `driftid replay`.
pub fn run(a: &ReplayArgs) -> anyhow::Result<()> {
    let out_path = a
        .out
        .clone()
        .unwrap_or_else(|| a.recording.with_extension("firmware.csv"));
    let mut outputs = output::Outputs::new(&[&a.recording], a.force);
    outputs.check(&out_path, "--out", output::Made::Csv(estimates_header()))?;
    if let Some(raw) = &a.raw {
        outputs.check(raw, "--raw", output::Made::RawLog)?;
    }
    let timeout = super::args::to_duration(a.timeout_s, "--timeout-s")?;
    let silence = super::args::to_duration(a.silence_s, "--silence-s")?;
    let rec = recording::read_recording(&a.recording)?;
    let config = firmware_config(a, &rec)?;
    let samples = replay::link_samples(&rec.samples);
    let port = port::open(&a.port, a.baud)?;
    let writer = port::writer_of(&port)?;
    let mut raw = match &a.raw {
        Some(p) => Some(output::open_log(p, "--raw", a.force)?),
        None => None,
    };
    let opts = replay::ReplayOptions {
        config,
        shutdown: a.shutdown,
        timeout,
        silence,
    };
    eprintln!(
        "driftid replay: {} samples from {} into {}",
        samples.len(),
        a.recording.display(),
        a.port
    );
    let verbose = a.verbose;
    // Estimates are written as they arrive to a temporary file beside the output, renamed into
    // place when the replay succeeds: a replay that fails leaves no output (and an earlier one
    // as it was). What the firmware sent is still in the --raw log, if given.
    let mut w = AtomicFile::create(&out_path)?;
    writeln!(w, "{}", estimates_header())?;
    let mut write_err: Option<std::io::Error> = None;
    let total_steps = (rec.samples.last().map_or(0.0, |s| s.t_s) / a.period_s).ceil() as u64;
    let outcome = replay::replay(
        port,
        writer,
        &samples,
        &opts,
        || true,
        |bytes| {
            if let Some(r) = raw.as_mut() {
                r.write_all(bytes)?;
                r.flush()?;
            }
            Ok(())
        },
        |m| match m {
            protocol::Message::Estimate(e) => {
                if write_err.is_none() {
                    if let Err(err) = writeln!(w, "{}", estimate_row(e)) {
                        write_err = Some(err);
                    }
                }
                if verbose || e.step % 60 == 0 {
                    eprintln!("[{}/{}] {}", e.step + 1, total_steps, link::describe(m))
                }
            }
            protocol::Message::Fault(_) | protocol::Message::Hello(_) => {
                eprintln!("{}", link::describe(m))
            }
            _ => {}
        },
    );
    if let Some(err) = write_err {
        return Err(err).with_context(|| format!("writing {}", out_path.display()));
    }
    let outcome = outcome?;
    w.commit()?;
    print_outcome(&outcome, &out_path);
    super::common::trusted_or(fault_reasons(&outcome.faults))
}

/// The firmware's filter configuration for recording `rec`: `--period-s`, `--arw`,
/// `--gate-nis`, and the raw noise from `--raw-sigma` or 1e-5 g per 60-s mean at the
/// recording's mean sample interval; the site from its metadata.
fn firmware_config(a: &ReplayArgs, rec: &recording::Recording) -> anyhow::Result<Config> {
    let rate_s = if rec.samples.len() > 1 {
        (rec.samples[rec.samples.len() - 1].t_s - rec.samples[0].t_s)
            / (rec.samples.len() - 1) as f64
    } else {
        1.0
    };
    let g = rec.meta.gravity_mps2.unwrap_or(9.80665);
    let sigma = a.raw_sigma.unwrap_or(1e-5 * g * (60.0 / rate_s).sqrt());
    let base = Config {
        filter_period_s: a.period_s,
        raw_sigma_mps2: [sigma; 3],
        arw_deg2_per_h: a.arw,
        gate_nis: a.gate_nis,
        status_every: 0,
        ..Config::default()
    };
    replay::config_for(&rec.meta, base)
}

/// The replay's outcome on stderr: the firmware's final status, what was written where, and
/// the last estimate's coefficients with their 1σ.
fn print_outcome(outcome: &replay::ReplayOutcome, out_path: &std::path::Path) {
    if let Some(s) = outcome.final_status() {
        eprintln!("{}", link::describe(&protocol::Message::Status(*s)));
    }
    eprintln!(
        "driftid replay: {} estimates written to {} in {:.1} s; link from the firmware: {}",
        outcome.estimates.len(),
        out_path.display(),
        outcome.elapsed_s,
        outcome.rx
    );
    if let Some(e) = outcome.estimates.last() {
        for (i, n) in COEFFICIENT_NAMES.iter().enumerate() {
            let (v, s) = (e.state[3 + i], e.sigma[3 + i]);
            eprintln!("  {n:>4} = {}", crate::format::pm(v, s));
        }
    }
}

/// The firmware's faults as reasons not to trust the estimates. A refused checkpoint is not one:
/// the firmware then started the run again from the beginning, and the replay followed.
fn fault_reasons(faults: &[protocol::Fault]) -> Vec<String> {
    faults
        .iter()
        .filter(|f| f.code != protocol::FaultCode::CheckpointRefused)
        .map(|f| {
            format!(
                "the firmware reported a fault: {:?} at update step {}: {}",
                f.code, f.step, f.detail
            )
        })
        .collect()
}
