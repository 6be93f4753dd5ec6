//! `driftid simulate`: write a simulated recording and its truth.

use std::path::PathBuf;

use anyhow::Context as _;

use crate::simulate::{
    self, Fault, InjectedEffect, Scenario, EFFECT_SYNTAX_HELP, FAULT_SYNTAX_HELP,
};

/// Scenario presets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    /// The paper's Table 1 coefficients at 39.1° N, 60 h at 1 s.
    #[default]
    Paper,
}

fn parse_effect(s: &str) -> Result<InjectedEffect, String> {
    s.parse()
}

fn parse_fault(s: &str) -> Result<Fault, String> {
    s.parse()
}

/// Simulate a recording (NAME.csv) and write its truth (NAME.truth.json).
#[derive(Clone, Debug, clap::Args)]
pub struct SimulateArgs {
    /// Scenario preset.
    #[arg(long, value_enum, default_value_t = Preset::Paper)]
    pub scenario: Preset,
    /// Duration, hours (preset: 60).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::hours_or_zero)]
    pub hours: Option<f64>,
    /// Sample interval, seconds (preset: 1).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::rate_s)]
    pub rate_s: Option<f64>,
    /// Random seed (preset: 1).
    #[arg(long, allow_hyphen_values = true)]
    pub seed: Option<u64>,
    /// Latitude, degrees (preset: 39.1). Gravity and the default accelerometer noise
    /// (1e-5 g per 60-s mean) follow it.
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::latitude_deg)]
    pub latitude_deg: Option<f64>,
    /// Output recording; the truth goes to the same name with .truth.json instead of .csv.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an existing --out (or its truth file) that is not a file simulate wrote.
    #[arg(long)]
    pub force: bool,
    /// Inject an effect.
    #[arg(long = "effect", value_name = "NAME=V1,V2,...", value_parser = parse_effect,
          allow_hyphen_values = true, long_help = EFFECT_SYNTAX_HELP)]
    pub effects: Vec<InjectedEffect>,
    /// Add a data fault to the written samples (not part of the truth model: what the
    /// data-quality screening must find).
    #[arg(long = "fault", value_name = "NAME=AXIS,V1,V2,V3", value_parser = parse_fault,
          allow_hyphen_values = true, long_help = FAULT_SYNTAX_HELP)]
    pub faults: Vec<Fault>,
    /// Write a temp_c column even without temp-drift.
    #[arg(long)]
    pub write_temp: bool,
    /// No gyro random walk and no accelerometer (or temperature sensor) noise.
    #[arg(long)]
    pub no_noise: bool,
    /// Platform orientation at t = 0 relative to local level ENU, deg: the paper's Euler angles
    /// tx,ty,tz (C = Rz(tz)·Ry(ty)·Rx(tx), passive). Written to the recording's metadata.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_name = "TX,TY,TZ"
    )]
    pub initial_orientation_deg: Option<Vec<f64>>,
    /// Set-up error: the true start minus the stated one, arcsec (tilt x, tilt y, azimuth).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_name = "TX,TY,AZ", value_parser = super::args::finite_f64)]
    pub start_error_arcsec: Option<Vec<f64>>,
    /// Set-up error: the recorder's clock runs fast by this much, ppm.
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::finite_f64)]
    pub clock_error_ppm: Option<f64>,
    /// Set-up error: the metadata latitude minus the true one, deg.
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::finite_f64)]
    pub latitude_error_deg: Option<f64>,
    /// Set-up error: the metadata gravity's relative error, ppm.
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::finite_f64)]
    pub gravity_error_ppm: Option<f64>,
    /// Set-up error: a daily tilt of the apparent vertical, amplitudes about east and north, arcsec.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_name = "EAST,NORTH", value_parser = super::args::finite_f64)]
    pub vertical_tilt_arcsec: Option<Vec<f64>>,
    /// Set-up error: a gyro drift trend the set-up puts on the run, deg/h per h on x, y, z.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_name = "KX,KY,KZ", value_parser = super::args::finite_f64)]
    pub drift_trend_error_deg_h_per_h: Option<Vec<f64>>,
    /// Draw every set-up error from the default set-up priors with the seed (identify's
    /// defaults; the latitude uniform within half its last written digit: ±0.05 deg for 39.1).
    #[arg(long)]
    pub setup_errors_from_priors: bool,
    /// Logger: each sample is the mean over its interval (centred on its stamp), not the value
    /// at the stamp (a log of averages).
    #[arg(long)]
    pub averaged: bool,
    /// Logger: each stamp after the first is off its sampling time by a uniform draw within
    /// ± this many seconds (a real clock's jitter; below a quarter of the interval).
    #[arg(long, value_parser = super::args::finite_f64)]
    pub time_jitter_s: Option<f64>,
    /// Logger: stamps written rounded to this many decimals of a second (e.g. 3 for a logger
    /// writing milliseconds).
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=15))]
    pub time_decimals: Option<u32>,
}

impl SimulateArgs {
    /// The scenario these arguments describe.
    pub(crate) fn scenario(&self) -> anyhow::Result<Scenario> {
        let mut s = match self.scenario {
            Preset::Paper => Scenario::paper(),
        };
        if let Some(l) = self.latitude_deg {
            s.latitude_deg = l;
            s.accel_sigma_mps2 = 1e-5 * s.gravity();
        }
        if let Some(h) = self.hours {
            s.hours = h;
        }
        if let Some(r) = self.rate_s {
            s.rate_s = r;
        }
        if let Some(seed) = self.seed {
            s.seed = seed;
        }
        s.effects = self.effects.clone();
        s.write_temp = self.write_temp;
        if let Some(o) = &self.initial_orientation_deg {
            match o.as_slice() {
                [tx, ty, tz] if o.iter().all(|v| v.is_finite()) => s.initial_orientation_deg = [*tx, *ty, *tz],
                _ => anyhow::bail!("--initial-orientation-deg takes three finite angles tx,ty,tz in degrees, got {o:?}"),
            }
        }
        if self.setup_errors_from_priors {
            let priors = crate::identify::setup::SetupPriors::default();
            let half = priors.latitude_sigma(s.latitude_deg) * 3f64.sqrt();
            s.setup_errors = crate::simulate::SetupErrors::draw(&priors, half, s.seed);
        }
        let e = &mut s.setup_errors;
        if let Some(v) = &self.start_error_arcsec {
            match v.as_slice() {
                [a, b, c] => e.start_arcsec = [*a, *b, *c],
                _ => anyhow::bail!("--start-error-arcsec takes three angles TX,TY,AZ in arcsec"),
            }
        }
        if let Some(v) = &self.vertical_tilt_arcsec {
            match v.as_slice() {
                [a, b] => e.vertical_tilt_arcsec = [*a, *b],
                _ => anyhow::bail!(
                    "--vertical-tilt-arcsec takes two amplitudes EAST,NORTH in arcsec"
                ),
            }
        }
        if let Some(v) = &self.drift_trend_error_deg_h_per_h {
            match v.as_slice() {
                [a, b, c] => e.drift_trend_deg_h_per_h = [*a, *b, *c],
                _ => anyhow::bail!(
                    "--drift-trend-error-deg-h-per-h takes three trends KX,KY,KZ in deg/h per h"
                ),
            }
        }
        e.clock_ppm = self.clock_error_ppm.unwrap_or(e.clock_ppm);
        e.latitude_deg = self.latitude_error_deg.unwrap_or(e.latitude_deg);
        e.gravity_ppm = self.gravity_error_ppm.unwrap_or(e.gravity_ppm);
        if self.no_noise {
            s = s.without_noise();
        }
        s.logger = crate::simulate::Logger {
            averaged: self.averaged,
            time_jitter_s: self.time_jitter_s.unwrap_or(0.0),
            time_decimals: self.time_decimals,
        };
        s.validate().map_err(|e| {
            anyhow::anyhow!(
                "{e} (from --hours {}, --rate-s {}, --latitude-deg {} and the --effect values)",
                s.hours,
                s.rate_s,
                s.latitude_deg
            )
        })?;
        Ok(s)
    }
}

/// Runs `driftid simulate`.
pub fn run(args: &SimulateArgs) -> anyhow::Result<()> {
    let scenario = args.scenario().context("invalid simulation settings")?;
    // The outputs are checked before the simulation (write_simulation checks them again).
    let mut outputs = crate::output::Outputs::new(&[], args.force);
    outputs.check(&args.out, "--out", crate::output::Made::SimulatedRecording)?;
    let truth = simulate::truth_path_for(&args.out);
    outputs.check(&truth, "--out (its truth file)", crate::output::Made::Truth)?;
    let mut sim = simulate::simulate(&scenario);
    let mut applied = vec![];
    for f in &args.faults {
        let n = f.apply(&mut sim.samples);
        applied.push(format!("{f} ({n} samples changed)"));
    }
    if !applied.is_empty() {
        let d = sim.meta.description.get_or_insert_with(String::new);
        d.push_str(&format!(", faults: {}", applied.join(" ")));
    }
    let truth_path = simulate::write_simulation(&args.out, &sim, args.force)?;
    println!(
        "wrote {} ({} samples, {} h at {} s, seed {}) and {}",
        args.out.display(),
        sim.samples.len(),
        scenario.hours,
        scenario.rate_s,
        scenario.seed,
        truth_path.display()
    );
    for a in &applied {
        println!("fault {a}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: SimulateArgs,
    }

    #[test]
    fn parses_effects_and_overrides() {
        let cli = Cli::try_parse_from([
            "x",
            "--out",
            "r.csv",
            "--hours",
            "2",
            "--latitude-deg",
            "-10",
            "--effect",
            "acc-bias=1e-4,0,0",
            "--effect",
            "drift-markov=0.01,0.01,0.01:5,5,5",
            "--no-noise",
        ])
        .unwrap();
        let s = cli.args.scenario().unwrap();
        assert_eq!(s.hours, 2.0);
        assert_eq!(s.latitude_deg, -10.0);
        assert_eq!(s.effects.len(), 2);
        assert_eq!(s.arw_deg2_per_h, 0.0);
        assert_eq!(s.accel_sigma_mps2, 0.0);
        assert!(Cli::try_parse_from(["x", "--out", "r.csv", "--effect", "acc-bias=1"]).is_err());
        assert!(Cli::try_parse_from(["x"]).is_err());
    }

    #[test]
    fn writes_csv_and_truth() {
        let dir = std::env::temp_dir().join(format!("driftid-cli-sim-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("run.csv");
        let cli = Cli::try_parse_from([
            "x",
            "--out",
            out.to_str().unwrap(),
            "--hours",
            "0.01",
            "--effect",
            "temp-drift=0.01,0,0",
        ])
        .unwrap();
        run(&cli.args).unwrap();
        let rec = crate::recording::read_recording(&out).unwrap();
        assert_eq!(rec.samples.len(), 37);
        assert!(rec.has_temp);
        assert_eq!(rec.meta.latitude_deg, Some(39.1));
        let truth = simulate::read_truth(&dir.join("run.truth.json")).unwrap();
        assert_eq!(truth.coefficient_array(), simulate::PAPER_COEFFICIENTS);
        assert_eq!(truth.effects.len(), 1);
        std::fs::remove_dir_all(&dir).ok();
    }
}
