//! The truth simulator: accelerometer recordings of a space-stable platform whose gyros drift
//! by the paper's model (plus injectable effects), with the true values written beside them.
//!
//! Independent of the estimator core by design (its own DCM kinematics in [`dcm`] and
//! [`engine`]), so a bug in the filter math cannot hide in the truth. Conventions follow
//! `docs/model.md`: frame 0 = local ENU at latitude L fixed to the Earth, platform frame p
//! space-stable, C = C_0^p passive with C(0) = I, A = C [0, 0, g].
//!
//! Drift per platform axis i (deg/h, converted with π/180/3600):
//! w_d,i = D(i)_0 + Σ_j D(i)_j A_j + injected drift effects + ε_i, ε white with density
//! `arw_deg2_per_h`. Accelerometer sample: z = A + accelerometer effects + N(0, σ²),
//! σ = `accel_sigma_mps2`·sqrt(60 / rate_s) (`accel_sigma_mps2` is the std of a 60-s mean).

#![allow(clippy::needless_range_loop)]

pub(crate) mod dcm;
mod effects;
mod engine;
mod faults;

use std::collections::BTreeMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use nalgebra::{Matrix3, Vector3};
use rand_distr::{Distribution, StandardNormal};

pub use effects::InjectedEffect;
pub(crate) use effects::EFFECT_SYNTAX_HELP;
pub use engine::Simulator;
pub use faults::Fault;
pub(crate) use faults::FAULT_SYNTAX_HELP;

use crate::output::AtomicFile;
use crate::recording::{Metadata, RawSample, RecordingWriter};

/// Names of the 12 drift coefficients, in [`Scenario::coefficients`] order.
pub(crate) const COEFFICIENT_NAMES: [&str; 12] = [
    "DX0", "DXx", "DXy", "DXz", "DY0", "DYx", "DYy", "DYz", "DZ0", "DZx", "DZy", "DZz",
];

/// The paper's Table 1 coefficients (deg/h and deg/h/(m/s²)).
pub(crate) const PAPER_COEFFICIENTS: [f64; 12] = [
    0.5, -0.1, -0.05, -0.05, -0.5, 0.05, 0.1, 0.05, 0.5, -0.05, 0.05, -0.1,
];

/// Platform temperature profile, °C:
/// T(t) = base + amp·sin(2π t / period) + step·(1 − exp(−t / step_tau)); the file gets
/// T(t) + N(0, noise²).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TempProfile {
    pub base_c: f64,
    pub amplitude_c: f64,
    pub period_h: f64,
    pub step_c: f64,
    pub step_tau_h: f64,
    pub noise_c: f64,
}

impl Default for TempProfile {
    fn default() -> Self {
        TempProfile {
            base_c: 20.0,
            amplitude_c: 0.8,
            period_h: 30.0,
            step_c: 0.3,
            step_tau_h: 5.0,
            noise_c: 0.01,
        }
    }
}

impl TempProfile {
    /// Smooth temperature at t, °C.
    pub fn at(&self, t_s: f64) -> f64 {
        let th = t_s / 3600.0;
        self.base_c
            + self.amplitude_c * (std::f64::consts::TAU * th / self.period_h).sin()
            + self.step_c * (1.0 - (-th / self.step_tau_h).exp())
    }
}

fn default_max_substep() -> f64 {
    1.0
}

/// Metadata key of the platform's initial orientation (deg, `tx, ty, tz`).
pub(crate) const INITIAL_ORIENTATION_KEY: &str = "initial_orientation_deg";

/// Everything that defines a simulated run.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Scenario {
    /// Preset name this scenario started from (informational).
    #[serde(default)]
    pub name: String,
    /// Latitude, deg.
    pub latitude_deg: f64,
    /// Gravity, m/s²; `None`: WGS-84 normal gravity at the latitude.
    pub gravity_mps2: Option<f64>,
    /// Duration, h.
    pub hours: f64,
    /// Sample interval, s.
    pub rate_s: f64,
    /// Seed of all random streams.
    pub seed: u64,
    /// DX0 DXx DXy DXz DY0 DYx DYy DYz DZ0 DZx DZy DZz: deg/h and deg/h/(m/s²).
    pub coefficients: [f64; 12],
    /// Gyro angle-random-walk density, deg²/h.
    pub arw_deg2_per_h: f64,
    /// Accelerometer noise: std of one 60-s average, m/s².
    pub accel_sigma_mps2: f64,
    /// Injected effects.
    pub effects: Vec<InjectedEffect>,
    /// Write a `temp_c` column even without `temp-drift`.
    pub write_temp: bool,
    /// Temperature profile (used by `temp-drift` and the `temp_c` column).
    #[serde(default)]
    pub temp_profile: TempProfile,
    /// Longest integration substep, s (≤ 1; finer if `rate_s` is shorter).
    #[serde(default = "default_max_substep")]
    pub max_substep_s: f64,
    /// Platform orientation at t = 0 relative to local level ENU: the paper's Euler angles
    /// (C = Rz(tz)·Ry(ty)·Rx(tx), passive), deg. Zero: a level, north-aligned start.
    #[serde(default)]
    pub initial_orientation_deg: [f64; 3],
    /// Errors of the set-up the recording states as exact (zero: none).
    #[serde(default)]
    pub setup_errors: SetupErrors,
    /// How the logger writes its samples (default: the value at each exact stamp).
    #[serde(default, skip_serializing_if = "Logger::is_plain")]
    pub logger: Logger,
}

/// How a logger writes its samples: values or interval means, and its time stamps' jitter and
/// rounding (docs/recording-format.md, "Rates and gaps").
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Logger {
    /// Each sample is the mean of the specific force over its interval, centred on its stamp
    /// ([t − Δ/2, t + Δ/2]; the first, at t = 0, extrapolated to second order over the half
    /// before the run's start), not the value at the stamp.
    #[serde(default)]
    pub averaged: bool,
    /// Each stamp after the first is off its sampling time by a uniform draw within ± this, s.
    #[serde(default)]
    pub time_jitter_s: f64,
    /// Stamps written rounded to this many decimals of a second.
    #[serde(default)]
    pub time_decimals: Option<u32>,
}

impl Logger {
    /// The default logger: exact stamps, values at them.
    pub(crate) fn is_plain(&self) -> bool {
        *self == Logger::default()
    }

    /// The stamp written for sampling time `t` (s), `jitter` a draw in [−1, 1].
    pub(crate) fn stamp(&self, t: f64, jitter: f64) -> f64 {
        let t = if t == 0.0 {
            t
        } else {
            t + self.time_jitter_s * jitter
        };
        match self.time_decimals {
            Some(d) => {
                let f = 10f64.powi(d as i32);
                (t * f).round() / f
            }
            None => t,
        }
    }
}

/// What the recording's set-up gets wrong: the true start, clock, latitude, gravity and
/// apparent vertical differ from what the metadata and the time stamps say.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SetupErrors {
    /// The true start minus the stated one, arcsec: tilt about x, tilt about y, azimuth (added
    /// to the Euler angles tx, ty, tz).
    pub start_arcsec: [f64; 3],
    /// Recorder clock rate error, ppm: a stamp reads (1 + ppm·1e-6) × the true time.
    pub clock_ppm: f64,
    /// The metadata latitude (the scenario's) minus the true one, deg.
    pub latitude_deg: f64,
    /// The metadata gravity's relative error, ppm.
    pub gravity_ppm: f64,
    /// Daily tilt of the apparent vertical: amplitudes about east (∝ cos ωt) and north
    /// (∝ sin ωt), arcsec.
    pub vertical_tilt_arcsec: [f64; 2],
    /// Its period, h (0: 24).
    pub vertical_tilt_period_h: f64,
    /// A gyro drift that follows the solar day (a laboratory's thermal cycle), deg/h: per axis
    /// x, y, z the amplitude in phase (∝ cos Ωt) and in quadrature (∝ sin Ωt), Ω = 2π/24 h.
    #[serde(default)]
    pub daily_drift_deg_h: [f64; 6],
    /// A gyro drift that changes steadily over the run (a laboratory's slower temperature
    /// changes, the gyros' run-in), deg/h per h, per axis x, y, z.
    #[serde(default)]
    pub drift_trend_deg_h_per_h: [f64; 3],
}

impl SetupErrors {
    /// Errors drawn from the set-up priors (each component N(0, prior 1σ)) with `seed`: the
    /// calibration sweeps' recordings. The latitude is drawn uniform within ±`latitude_half_deg`,
    /// the rounding of its last written digit (the default prior's model).
    pub fn draw(
        priors: &crate::identify::setup::SetupPriors,
        latitude_half_deg: f64,
        seed: u64,
    ) -> Self {
        let mut rng = engine::rng(seed, engine::stream::SETUP);
        let latitude_deg = latitude_half_deg * (2.0 * rand::Rng::random::<f64>(&mut rng) - 1.0);
        let mut n = || -> f64 { StandardNormal.sample(&mut rng) };
        SetupErrors {
            start_arcsec: [
                priors.tilt_arcsec * n(),
                priors.tilt_arcsec * n(),
                priors.azimuth_arcsec * n(),
            ],
            clock_ppm: priors.clock_sigma_ppm * n(),
            latitude_deg,
            gravity_ppm: priors.gravity_sigma_ppm * n(),
            vertical_tilt_arcsec: [
                priors.vertical_tilt_arcsec * n() * std::f64::consts::SQRT_2,
                priors.vertical_tilt_arcsec * n() * std::f64::consts::SQRT_2,
            ],
            vertical_tilt_period_h: priors.vertical_tilt_period_h,
            daily_drift_deg_h: [(); 6].map(|_| priors.daily_drift_deg_h * n()),
            // Drawn last: the earlier draws of a seed are those of the recordings made before.
            drift_trend_deg_h_per_h: [(); 3].map(|_| priors.drift_trend_deg_h_per_day / 24.0 * n()),
        }
    }

    /// The apparent vertical's tilt at true time `t_s` as a rotation vector in ENU, rad.
    fn vertical_tilt_rad(&self, t_s: f64) -> Vector3<f64> {
        let p = if self.vertical_tilt_period_h > 0.0 {
            self.vertical_tilt_period_h
        } else {
            24.0
        };
        let w = 2.0 * std::f64::consts::PI / (p * 3600.0);
        let k = std::f64::consts::PI / (180.0 * 3600.0);
        Vector3::new(
            self.vertical_tilt_arcsec[0] * k * (w * t_s).cos(),
            self.vertical_tilt_arcsec[1] * k * (w * t_s).sin(),
            0.0,
        )
    }
}

impl Scenario {
    /// The paper's scenario: Table 1 coefficients, 39.1° N, normal gravity, 60 h at 1 s, seed 1,
    /// ARW 1e-8 deg²/h, accelerometer 1e-5 g per 60-s mean.
    pub fn paper() -> Self {
        let latitude_deg = 39.1;
        Scenario {
            name: "paper".into(),
            latitude_deg,
            gravity_mps2: None,
            hours: 60.0,
            rate_s: 1.0,
            seed: 1,
            coefficients: PAPER_COEFFICIENTS,
            arw_deg2_per_h: 1e-8,
            accel_sigma_mps2: 1e-5 * dcm::normal_gravity(latitude_deg.to_radians()),
            effects: Vec::new(),
            write_temp: false,
            temp_profile: TempProfile::default(),
            max_substep_s: 1.0,
            initial_orientation_deg: [0.0; 3],
            setup_errors: SetupErrors::default(),
            logger: Logger::default(),
        }
    }

    /// The gravity used: `gravity_mps2` or normal gravity at the latitude.
    pub fn gravity(&self) -> f64 {
        self.gravity_mps2
            .unwrap_or_else(|| dcm::normal_gravity(self.latitude_deg.to_radians()))
    }

    /// Zero gyro random walk and accelerometer noise (temperature sensor noise too).
    pub fn without_noise(mut self) -> Self {
        self.arw_deg2_per_h = 0.0;
        self.accel_sigma_mps2 = 0.0;
        self.temp_profile.noise_c = 0.0;
        self
    }

    /// Number of samples: t = 0, rate_s, … up to hours·3600 inclusive.
    pub(crate) fn sample_count(&self) -> u64 {
        ((self.hours * 3600.0) / self.rate_s + 1e-9).floor() as u64 + 1
    }

    /// Whether the recording gets a `temp_c` column.
    pub(crate) fn has_temp(&self) -> bool {
        self.write_temp
            || self.effects.iter().any(|e| {
                matches!(
                    e,
                    InjectedEffect::TempDrift { .. } | InjectedEffect::AccTemp { .. }
                )
            })
    }

    /// Checks ranges: latitude in [−90, 90], hours ≥ 0, rate_s > 0, finite coefficients,
    /// non-negative noise, valid effects, at most 1e8 samples.
    pub(crate) fn validate(&self) -> Result<(), String> {
        let fin = |x: f64, what: &str| {
            if x.is_finite() {
                Ok(())
            } else {
                Err(format!("{what} must be finite"))
            }
        };
        fin(self.latitude_deg, "latitude_deg")?;
        if !(-90.0..=90.0).contains(&self.latitude_deg) {
            return Err(format!(
                "latitude_deg {} is outside [-90, 90]",
                self.latitude_deg
            ));
        }
        if let Some(g) = self.gravity_mps2 {
            if !(g.is_finite() && g > 0.0) {
                return Err(format!("gravity_mps2 {g} must be positive"));
            }
        }
        if !(self.hours.is_finite() && self.hours >= 0.0) {
            return Err(format!("hours {} must be >= 0", self.hours));
        }
        if !(self.rate_s.is_finite() && self.rate_s > 0.0) {
            return Err(format!("rate_s {} must be > 0", self.rate_s));
        }
        if !(self.max_substep_s.is_finite() && self.max_substep_s > 0.0) {
            return Err(format!("max_substep_s {} must be > 0", self.max_substep_s));
        }
        for (c, n) in self.coefficients.iter().zip(COEFFICIENT_NAMES) {
            fin(*c, n)?;
        }
        if !(self.arw_deg2_per_h.is_finite() && self.arw_deg2_per_h >= 0.0) {
            return Err("arw_deg2_per_h must be >= 0".into());
        }
        if !(self.accel_sigma_mps2.is_finite() && self.accel_sigma_mps2 >= 0.0) {
            return Err("accel_sigma_mps2 must be >= 0".into());
        }
        let tp = &self.temp_profile;
        for (v, n) in [
            (tp.base_c, "temp base"),
            (tp.amplitude_c, "temp amplitude"),
            (tp.step_c, "temp step"),
        ] {
            fin(v, n)?;
        }
        if !(tp.period_h > 0.0 && tp.step_tau_h > 0.0 && tp.noise_c >= 0.0) {
            return Err("temperature profile: period and step tau must be > 0, noise >= 0".into());
        }
        for e in &self.effects {
            e.validate()?;
        }
        self.validate_setup_errors()?;
        self.validate_logger()?;
        let n = (self.hours * 3600.0) / self.rate_s;
        if n > 1e8 {
            return Err(format!("{n:.0} samples is too many (at most 1e8)"));
        }
        Ok(())
    }

    /// The set-up errors within their ranges (clock ±1e5 ppm, latitude ±10°, gravity ±1e5 ppm,
    /// angles ±3600″, daily drift ±1 deg/h, drift trend ±0.1 deg/h per h).
    fn validate_setup_errors(&self) -> Result<(), String> {
        let se = &self.setup_errors;
        if !(se.clock_ppm.abs() < 1e5
            && se.latitude_deg.abs() <= 10.0
            && se.gravity_ppm.abs() < 1e5
            && se.start_arcsec.iter().all(|a| a.abs() <= 3600.0)
            && se.vertical_tilt_arcsec.iter().all(|a| a.abs() <= 3600.0)
            && se.vertical_tilt_period_h >= 0.0
            && se.daily_drift_deg_h.iter().all(|a| a.abs() <= 1.0)
            && se.drift_trend_deg_h_per_h.iter().all(|a| a.abs() <= 0.1))
        {
            return Err(format!(
                "set-up errors out of range (clock ±1e5 ppm, latitude ±10 deg, gravity ±1e5 ppm, angles ±3600 arcsec, daily drift ±1 deg/h, drift trend ±0.1 deg/h per h): {se:?}"
            ));
        }
        Ok(())
    }

    /// The logger's time-stamp jitter and rounding below a quarter of the sample interval (else
    /// stamps could swap order), at most 15 decimals.
    fn validate_logger(&self) -> Result<(), String> {
        let lg = &self.logger;
        let rounding = lg
            .time_decimals
            .map_or(0.0, |d| 0.5 * 10f64.powi(-(d.min(300) as i32)));
        if !(lg.time_jitter_s.is_finite() && lg.time_jitter_s >= 0.0)
            || lg.time_jitter_s + rounding >= 0.25 * self.rate_s
            || lg.time_decimals.is_some_and(|d| d > 15)
        {
            return Err(format!(
                "time-stamp jitter {} s and rounding to {:?} decimals must stay below a quarter of the interval {} s (decimals at most 15)",
                lg.time_jitter_s, lg.time_decimals, self.rate_s
            ));
        }
        Ok(())
    }
}

/// The specific force (with the apparent vertical's tilt, `err`) at true time `t`, s.
fn force_at(sim: &mut Simulator, err: SetupErrors, g: f64, t: f64, max_sub: f64) -> Vector3<f64> {
    sim.advance_to(t, max_sub);
    let mut a = sim.specific_force();
    if err.vertical_tilt_arcsec != [0.0; 2] {
        a += sim.c_0p() * err.vertical_tilt_rad(t).cross(&Vector3::new(0.0, 0.0, g));
    }
    a
}

/// The mean specific force over [`from`, `to`] (true times, s) by the midpoint rule on steps of
/// at most 1 s (its own error A''·(1 s)²/24 ~ 2e-9 m/s²).
fn interval_mean(
    sim: &mut Simulator,
    err: SetupErrors,
    g: f64,
    from: f64,
    to: f64,
    max_sub: f64,
) -> Vector3<f64> {
    let m = (to - from).ceil().max(2.0);
    let w = (to - from) / m;
    let sum = (0..m as u64).fold(Vector3::zeros(), |acc, j| {
        acc + force_at(sim, err, g, from + (j as f64 + 0.5) * w, max_sub)
    });
    sum / m
}

/// A simulated recording with its truth.
#[derive(Clone, Debug)]
pub struct Simulation {
    pub meta: Metadata,
    pub samples: Vec<RawSample>,
    pub truth: Truth,
}

/// What the simulation really did; written as `NAME.truth.json` beside `NAME.csv`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Truth {
    /// The full scenario.
    pub scenario: Scenario,
    /// The 12 coefficients by name (DX0 … DZz).
    pub coefficients: BTreeMap<String, f64>,
    /// Units of the quantities above.
    pub units: BTreeMap<String, String>,
    /// The injected effects (same as `scenario.effects`).
    pub effects: Vec<InjectedEffect>,
    /// Gravity used, m/s².
    pub gravity_mps2: f64,
    /// Number of samples written.
    pub sample_count: u64,
    /// Time of the last sample, s.
    pub final_t_s: f64,
    /// θ = (tx, ty, tz) of C_0^p at the last sample, rad, unwrapped (continuous from 0).
    pub final_theta_rad: [f64; 3],
    /// C_0^p at the last sample, row-major.
    pub final_c_0p: [[f64; 3]; 3],
}

impl Truth {
    /// The 12 true coefficients in `COEFFICIENT_NAMES` order.
    pub fn coefficient_array(&self) -> [f64; 12] {
        self.scenario.coefficients
    }

    /// The true value of every model parameter this run determines, by the catalog's parameter
    /// names: the 12 drift coefficients and each injected deterministic effect's parameters (a
    /// Gauss–Markov drift is a random process: no parameter truth). With g² drift the constant
    /// D(i)0 a static run sees is D(i)0 + g²·D(i)zz (|A| = g merges them), and the identifiable
    /// g² combinations are xx−zz, yy−zz, xy, xz, yz.
    pub(crate) fn parameter_values(&self) -> BTreeMap<String, f64> {
        let mut out: BTreeMap<String, f64> = COEFFICIENT_NAMES
            .iter()
            .zip(self.scenario.coefficients)
            .map(|(n, v)| (n.to_string(), v))
            .collect();
        let xyz = ['X', 'Y', 'Z'];
        let lower = ['x', 'y', 'z'];
        for e in &self.effects {
            let mut put = |name: String, v: f64| {
                *out.entry(name).or_insert(0.0) += v;
            };
            match e {
                InjectedEffect::G2 {
                    d_deg_h_per_mps2_sq: d,
                } => {
                    let g2 = self.gravity_mps2 * self.gravity_mps2;
                    for (i, a) in xyz.iter().enumerate() {
                        // Order xx, xy, xz, yy, yz, zz.
                        let [xx, xy, xz, yy, yz, zz] = d[i];
                        put(format!("D{a}0"), g2 * zz);
                        put(format!("G{a}xx-zz"), xx - zz);
                        put(format!("G{a}yy-zz"), yy - zz);
                        put(format!("G{a}xy"), xy);
                        put(format!("G{a}xz"), xz);
                        put(format!("G{a}yz"), yz);
                    }
                }
                InjectedEffect::AccBias { b_mps2 } => {
                    for (i, v) in b_mps2.iter().enumerate() {
                        put(format!("BA{}", lower[i]), *v);
                    }
                }
                InjectedEffect::AccScale { s_ppm } => {
                    for (i, v) in s_ppm.iter().enumerate() {
                        put(format!("SA{}", lower[i]), *v);
                    }
                }
                InjectedEffect::AccMisalign { m_rad } => {
                    for (name, v) in ["Mxy", "Mxz", "Myx", "Myz", "Mzx", "Mzy"].iter().zip(m_rad) {
                        put(name.to_string(), *v);
                    }
                }
                InjectedEffect::DriftTrend { k_deg_h_per_h } => {
                    for (i, v) in k_deg_h_per_h.iter().enumerate() {
                        put(format!("T{}", xyz[i]), *v);
                    }
                }
                InjectedEffect::TempDrift { c_deg_h_per_c } => {
                    for (i, v) in c_deg_h_per_c.iter().enumerate() {
                        put(format!("K{}", xyz[i]), *v);
                    }
                }
                InjectedEffect::AccTemp { k_mps2_per_c } => {
                    for (i, v) in k_mps2_per_c.iter().enumerate() {
                        put(format!("TA{}", lower[i]), *v);
                    }
                }
                // Found as a drift step (`diagnose::drift_step`) when it explains a misfit.
                InjectedEffect::DriftStep { a_deg_h, .. } => {
                    for (i, v) in a_deg_h.iter().enumerate() {
                        put(format!("DS{}", xyz[i]), *v);
                    }
                }
                // Found as a warm-up (`diagnose::warmup`): its amplitudes, exact when the
                // profiled time constant is the injected one.
                InjectedEffect::DriftTransient { a_deg_h, .. } => {
                    for (i, v) in a_deg_h.iter().enumerate() {
                        put(format!("AW{}", xyz[i]), *v);
                    }
                }
                // Outside the catalog: no parameter of an identified model is theirs.
                InjectedEffect::DriftMarkov { .. }
                | InjectedEffect::DriftSine { .. }
                | InjectedEffect::AccNorth { .. } => {}
            }
        }
        out
    }
}

fn units() -> BTreeMap<String, String> {
    [
        ("coefficients D0", "deg/h"),
        ("coefficients Dx Dy Dz", "deg/h/(m/s^2)"),
        ("latitude_deg", "deg"),
        ("gravity_mps2", "m/s^2"),
        ("hours", "h"),
        ("rate_s", "s"),
        (
            "arw_deg2_per_h",
            "deg^2/h (angle random walk variance density)",
        ),
        (
            "accel_sigma_mps2",
            "m/s^2 (std of one 60-s average; raw samples carry sigma*sqrt(60/rate_s))",
        ),
        ("final_theta_rad", "rad"),
        ("g2", "deg/h/(m/s^2)^2"),
        ("acc-bias", "m/s^2"),
        ("acc-scale", "ppm"),
        ("acc-misalign", "rad"),
        ("drift-trend", "deg/h per h"),
        ("drift-markov", "sigma deg/h, tau h"),
        ("temp-drift", "deg/h per deg C"),
        ("acc-temp", "m/s^2 per deg C"),
        ("drift-step", "deg/h : h (size per axis : step time)"),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect()
}

fn to_rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = m[(i, j)];
        }
    }
    r
}

/// Accelerometer model: z = K A + b with K = I + diag(scale) + misalignment.
fn accel_model(effects: &[InjectedEffect]) -> (Matrix3<f64>, Vector3<f64>) {
    let mut k = Matrix3::identity();
    let mut b = Vector3::zeros();
    for e in effects {
        match e {
            InjectedEffect::AccBias { b_mps2 } => b += Vector3::from(*b_mps2),
            InjectedEffect::AccScale { s_ppm } => {
                for i in 0..3 {
                    k[(i, i)] += s_ppm[i] * 1e-6;
                }
            }
            InjectedEffect::AccMisalign { m_rad } => {
                let [xy, xz, yx, yz, zx, zy] = *m_rad;
                k[(0, 1)] += xy;
                k[(0, 2)] += xz;
                k[(1, 0)] += yx;
                k[(1, 2)] += yz;
                k[(2, 0)] += zx;
                k[(2, 1)] += zy;
            }
            _ => {}
        }
    }
    (k, b)
}

/// A one-line description of the scenario for the recording's metadata.
pub(crate) fn describe(s: &Scenario) -> String {
    let mut d = format!(
        "driftid simulate: scenario {}, seed {}, {} h at {} s, latitude {} deg, arw {} deg^2/h, accel sigma {} m/s^2 per 60 s",
        if s.name.is_empty() { "custom" } else { &s.name },
        s.seed,
        s.hours,
        s.rate_s,
        s.latitude_deg,
        // Noise levels with the digits they are known to (issue 29: not 0.00009800897657048797).
        crate::format::sig(s.arw_deg2_per_h, 3),
        crate::format::sig(s.accel_sigma_mps2, 3)
    );
    if !s.effects.is_empty() {
        let e: Vec<String> = s.effects.iter().map(|e| e.to_string()).collect();
        d.push_str(&format!(", effects: {}", e.join(" ")));
    }
    d
}

/// A day at 60 s with a g² drift and an accelerometer bias the paper's model lacks: beside
/// them, acc-misalign's fit does not converge (Gauss–Newton swings between Mxy and Myx).
#[cfg(test)]
pub(crate) fn g2_and_acc_bias_day() -> Scenario {
    let mut sc = Scenario::paper();
    sc.hours = 24.0;
    sc.rate_s = 60.0;
    sc.effects = vec![
        InjectedEffect::G2 {
            d_deg_h_per_mps2_sq: [
                [5e-5, 0.0, 0.0, 0.0, 0.0, 0.0],
                [0.0, 5e-5, 0.0, 0.0, 0.0, 0.0],
                [0.0, 0.0, 5e-5, 0.0, 0.0, 0.0],
            ],
        },
        InjectedEffect::AccBias {
            b_mps2: [5e-4, -3e-4, 4e-4],
        },
    ];
    sc
}

/// `sc` simulated and prepared as `identify` prepares it, at the recording's latitude and
/// gravity with a level start: the fixture of the host's unit tests.
#[cfg(test)]
pub(crate) fn prepared(sc: &Scenario, cfg: &crate::identify::Config) -> crate::identify::Prepared {
    let sim = simulate(sc);
    let samples: Vec<estimator_core::Sample> = sim
        .samples
        .iter()
        .map(estimator_core::Sample::from)
        .collect();
    let site = estimator_core::Site::new(
        sim.meta
            .latitude_deg
            .expect("a simulated recording states its latitude"),
        sim.meta.gravity_mps2,
    );
    crate::identify::prepare(site, &samples, cfg).expect("a simulated recording prepares")
}

/// Simulates the scenario. Panics if [`Scenario::validate`] fails.
pub fn simulate(s: &Scenario) -> Simulation {
    if let Err(e) = s.validate() {
        panic!("invalid scenario: {e}");
    }
    let g = s.gravity();
    let err = s.setup_errors;
    let mut sim = Simulator::new(&as_it_truly_is(s, g));
    let clock = 1.0 + err.clock_ppm * 1e-6;
    let mut rng_acc = engine::rng(s.seed, engine::stream::ACCEL);
    let mut rng_temp = engine::rng(s.seed, engine::stream::TEMP);
    let mut rng_time = engine::rng(s.seed, engine::stream::TIMING);
    let sigma = s.accel_sigma_mps2 * (60.0 / s.rate_s).sqrt();
    let (k, b) = accel_model(&s.effects);
    let (acc_temp, acc_north) = temperature_and_north_pickup(&s.effects);
    let has_temp = s.has_temp();
    let max_sub = s.max_substep_s.min(1.0);
    let n = s.sample_count();
    let mut samples = Vec::with_capacity(n as usize);
    for i in 0..n {
        let t_stamp = i as f64 * s.rate_s;
        let t = t_stamp / clock;
        let north_before = acc_north.map(|_| sim.north());
        let a = logged_force(&mut sim, s, err, g, i == 0, t, clock, max_sub);
        let mut z = k * a + b + acc_temp * (s.temp_profile.at(t) - s.temp_profile.at(0.0));
        if let Some(kn) = acc_north {
            // North at the sample's time; over an averaging window the mean of its ends
            // (trapezoid: off by (ω·window)²/12 ≈ 2e-6 of k for a 60-s window).
            let north = match north_before {
                Some(n0) if s.logger.averaged => (n0 + sim.north()) * 0.5,
                _ => sim.north(),
            };
            z += kn.component_mul(&north);
        }
        if sigma > 0.0 {
            for j in 0..3 {
                let e: f64 = StandardNormal.sample(&mut rng_acc);
                z[j] += sigma * e;
            }
        }
        let temp_c = has_temp.then(|| {
            let mut tc = s.temp_profile.at(t);
            if s.temp_profile.noise_c > 0.0 {
                let e: f64 = StandardNormal.sample(&mut rng_temp);
                tc += s.temp_profile.noise_c * e;
            }
            tc
        });
        let jitter = if s.logger.time_jitter_s > 0.0 {
            rand::Rng::random_range(&mut rng_time, -1.0..=1.0)
        } else {
            0.0
        };
        samples.push(RawSample {
            t_s: s.logger.stamp(t_stamp, jitter),
            specific_force_mps2: [z.x, z.y, z.z],
            temp_c,
        });
    }
    let truth = truth_of(s, &sim, g, n);
    let meta = metadata_of(s, g);
    Simulation {
        meta,
        samples,
        truth,
    }
}

/// The scenario as the platform truly stands, set-up errors included: the metadata states the
/// scenario's latitude, the platform stands at the true one (the scenario's gravity `g` either
/// way: its change with 0.03° of latitude is 0.2 ppm), and starts off the stated orientation by
/// the start error.
fn as_it_truly_is(s: &Scenario, g: f64) -> Scenario {
    let err = s.setup_errors;
    let mut truly = s.clone();
    truly.latitude_deg -= err.latitude_deg;
    truly.gravity_mps2 = Some(g);
    for i in 0..3 {
        truly.initial_orientation_deg[i] += err.start_arcsec[i] / 3600.0;
    }
    truly
}

/// The accelerometers' pick-up summed over `effects`: of the temperature (m/s² per °C,
/// `acc-temp`) and of the local north (m/s² per unit, `acc-north`; `None` when absent).
fn temperature_and_north_pickup(
    effects: &[InjectedEffect],
) -> (Vector3<f64>, Option<Vector3<f64>>) {
    let acc_temp: Vector3<f64> = effects
        .iter()
        .filter_map(|e| match e {
            InjectedEffect::AccTemp { k_mps2_per_c } => Some(Vector3::from(*k_mps2_per_c)),
            _ => None,
        })
        .sum();
    let acc_north: Option<Vector3<f64>> = effects
        .iter()
        .filter_map(|e| match e {
            InjectedEffect::AccNorth { k_mps2 } => Some(Vector3::from(*k_mps2)),
            _ => None,
        })
        .reduce(|a, b| a + b);
    (acc_temp, acc_north)
}

/// What the logger writes for the sample at true time `t` (clock rate `clock`): the mean over
/// its interval when the logger averages (the run's `first` sample: from a second-order
/// expansion, its interval reaching before the start), else the value at `t`.
#[allow(clippy::too_many_arguments)]
fn logged_force(
    sim: &mut Simulator,
    s: &Scenario,
    err: SetupErrors,
    g: f64,
    first: bool,
    t: f64,
    clock: f64,
    max_sub: f64,
) -> Vector3<f64> {
    if s.logger.averaged {
        let half = 0.5 * s.rate_s / clock;
        if first {
            // [−Δ/2, Δ/2] reaches before the run's start: to second order its mean is
            // f(0) + (A₂ − 3A₁ + 2f(0))/4, A₁ and A₂ the means over [0, Δ/2] and [Δ/2, Δ]
            // (exact on a parabola), taken on a copy of the simulator.
            let f0 = force_at(sim, err, g, 0.0, max_sub);
            let mut probe = sim.clone();
            let a1 = interval_mean(&mut probe, err, g, 0.0, half, max_sub);
            let a2 = interval_mean(&mut probe, err, g, half, 2.0 * half, max_sub);
            f0 + (a2 - 3.0 * a1 + 2.0 * f0) / 4.0
        } else {
            interval_mean(sim, err, g, t - half, t + half, max_sub)
        }
    } else {
        force_at(sim, err, g, t, max_sub)
    }
}

/// The truth of a simulated run: its scenario and coefficients, and the platform's state at
/// the end (`n` samples simulated by `sim`; `g` the true gravity).
fn truth_of(s: &Scenario, sim: &Simulator, g: f64, n: u64) -> Truth {
    let coefficients = COEFFICIENT_NAMES
        .iter()
        .zip(s.coefficients)
        .map(|(n, v)| (n.to_string(), v))
        .collect();
    Truth {
        scenario: s.clone(),
        coefficients,
        units: units(),
        effects: s.effects.clone(),
        gravity_mps2: g,
        sample_count: n,
        final_t_s: sim.time_s(),
        final_theta_rad: sim.theta_rad(),
        final_c_0p: to_rows(&sim.c_0p()),
    }
}

/// The recording's metadata: the stated latitude and gravity (a misstatement in
/// `setup_errors` included), its description, and driftid's own mark.
fn metadata_of(s: &Scenario, g: f64) -> Metadata {
    let err = s.setup_errors;
    // Marks the file as driftid's own: a later `simulate --out` may replace it without --force
    // ([`crate::output::Made::SimulatedRecording`]); a recording of real data is never replaced.
    let (k, v) = crate::output::SIMULATED_KEY;
    let mut extra = vec![(k.to_string(), v.to_string())];
    if s.initial_orientation_deg != [0.0; 3] {
        let [tx, ty, tz] = s.initial_orientation_deg;
        extra.push((
            INITIAL_ORIENTATION_KEY.to_string(),
            format!("{tx:?}, {ty:?}, {tz:?}"),
        ));
    }
    Metadata {
        latitude_deg: Some(s.latitude_deg),
        gravity_mps2: Some(g * (1.0 + err.gravity_ppm * 1e-6)),
        description: Some(describe(s)),
        extra,
    }
}

/// `NAME.csv` → `NAME.truth.json` (any other name: `NAME.truth.json` appended).
pub(crate) fn truth_path_for(csv: &Path) -> PathBuf {
    let stem = match csv.extension() {
        Some(e) if e.eq_ignore_ascii_case("csv") => csv.with_extension(""),
        _ => csv.to_path_buf(),
    };
    let mut name = stem.file_name().unwrap_or_default().to_os_string();
    name.push(".truth.json");
    stem.with_file_name(name)
}

/// Writes the recording to `csv` and the truth beside it; returns the truth file's path.
///
/// Both or neither: the recording and the truth are first written in full to temporary files
/// beside them ([`crate::output`]); an error (or an interruption) up to there leaves the previous
/// pair as it was. Then, in this order: the previous truth file is removed, the recording is
/// renamed into place, the truth is renamed into place. Whatever step an interruption falls
/// after, a truth file never sits beside a recording it does not describe — the states in
/// between are "the old recording without a truth" and "the new recording without its truth"
/// (a truth file that is missing is reported by `--truth`; a stale one would silently give wrong
/// errors). Renaming the truth first, or the recording first without removing the old truth,
/// would each leave a mismatched pair.
///
/// Neither file is written over a file the user has ([`crate::output::check_output`]): an
/// existing recording that `simulate` did not write, or a truth file that is not one, is refused
/// unless `force`.
pub fn write_simulation(csv: &Path, sim: &Simulation, force: bool) -> anyhow::Result<PathBuf> {
    let tp = truth_path_for(csv);
    let mut outputs = crate::output::Outputs::new(&[], force);
    outputs.check(csv, "--out", crate::output::Made::SimulatedRecording)?;
    outputs.check(&tp, "--out (its truth file)", crate::output::Made::Truth)?;
    let file = AtomicFile::create(csv)?;
    let mut w = RecordingWriter::new(file, &sim.meta, sim.truth.scenario.has_temp())
        .with_context(|| format!("writing {}", csv.display()))?;
    for s in &sim.samples {
        w.write_sample(s)
            .with_context(|| format!("writing {}", csv.display()))?;
    }
    let csv_file = w
        .into_inner()
        .with_context(|| format!("writing {}", csv.display()))?;
    let mut truth_file = AtomicFile::create(&tp)?;
    truth_file
        .write_all(truth_json(&sim.truth)?.as_bytes())
        .with_context(|| format!("writing {}", tp.display()))?;
    // Only a file (or a link) is removed: a FIFO or a device node stays, and is written into.
    let removable = std::fs::symlink_metadata(&tp).map_or(true, |m| {
        m.file_type().is_file() || m.file_type().is_symlink()
    });
    match if removable {
        std::fs::remove_file(&tp)
    } else {
        Ok(())
    } {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e).with_context(|| format!("removing the previous {}", tp.display())),
    }
    csv_file.commit()?;
    truth_file.commit()?;
    Ok(tp)
}

fn truth_json(truth: &Truth) -> anyhow::Result<String> {
    Ok(serde_json::to_string_pretty(truth)? + "\n")
}

/// Reads a truth file and checks that its named coefficients agree with its scenario.
pub fn read_truth(path: &Path) -> anyhow::Result<Truth> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let truth: Truth = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a valid truth file", path.display()))?;
    for (name, v) in COEFFICIENT_NAMES.iter().zip(truth.scenario.coefficients) {
        match truth.coefficients.get(*name) {
            Some(c) if *c == v => {}
            Some(c) => anyhow::bail!(
                "{}: coefficient {name} = {c} disagrees with the scenario's {v}",
                path.display()
            ),
            None => anyhow::bail!("{}: coefficient {name} missing", path.display()),
        }
    }
    Ok(truth)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effect_syntax_round_trips() {
        let cases = [
            "acc-bias=1e-4,0,0",
            "acc-scale=100,-50,3",
            "acc-misalign=1e-4,0,0,2e-4,0,-1e-4",
            "drift-trend=0.01,0,0",
            "drift-markov=0.01,0.01,0.01:5,5,5",
            "temp-drift=0.001,0.002,0.003",
            "g2=1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16,17,18",
            "drift-step=0,0.002,0:30",
        ];
        for c in cases {
            let e: InjectedEffect = c.parse().unwrap();
            let back: InjectedEffect = e.to_string().parse().unwrap();
            assert_eq!(e, back, "{c}");
            let json = serde_json::to_value(&e).unwrap();
            assert_eq!(json["name"], e.name());
            assert_eq!(serde_json::from_value::<InjectedEffect>(json).unwrap(), e);
        }
        let g2: InjectedEffect = cases[6].parse().unwrap();
        match g2 {
            InjectedEffect::G2 {
                d_deg_h_per_mps2_sq: d,
            } => {
                assert_eq!(d[1][0], 7.0);
                assert_eq!(d[2][5], 18.0);
            }
            _ => unreachable!(),
        }
    }

    #[test]
    fn effect_syntax_errors() {
        for bad in [
            "acc-bias",
            "acc-bias=1,2",
            "acc-bias=1,2,x",
            "acc-bias=1,2,3:4,5,6",
            "drift-markov=1,1,1",
            "drift-markov=1,1,1:0,1,1",
            "drift-markov=-1,1,1:1,1,1",
            "nope=1,2,3",
            "acc-bias=1,2,inf",
            "drift-step=0,0.002,0",
            "drift-step=0,0.002,0:-1",
        ] {
            assert!(bad.parse::<InjectedEffect>().is_err(), "{bad}");
        }
    }

    #[test]
    fn a_drift_step_changes_the_drift_at_its_time() {
        // 0.002 deg/h on Y from 1 h: the drift rate's change from 1 s before to 1 s after, minus
        // the same run's without the step (the Earth's turn moves gravity in platform axes by
        // ~1.5e-4 rad in 2 s, so the paper drift itself changes by ~1e-4 deg/h), is the step on
        // Y and nothing else. The runs share their noise (same seed); they differ by the step's
        // 1 s of turn, 1e-8 rad, so 1e-6 deg/h bounds what is left.
        let change = |effects: &[&str]| {
            let mut sc = Scenario::paper();
            for e in effects {
                sc.effects.push(e.parse().unwrap());
            }
            let mut sim = engine::Simulator::new(&sc);
            sim.advance_to(3599.0, 1.0);
            let before = sim.drift_rate_rad_s();
            sim.advance_to(3601.0, 1.0);
            (sim.drift_rate_rad_s() - before) / dcm::RADPS_PER_DEG_H
        };
        let d = change(&["drift-step=0,0.002,0:1"]) - change(&[]);
        let want = [0.0, 0.002, 0.0];
        for i in 0..3 {
            assert!((d[i] - want[i]).abs() < 1e-6, "axis {i}: {d:?} deg/h");
        }
    }

    #[test]
    fn paper_scenario_defaults() {
        let s = Scenario::paper();
        assert_eq!(s.sample_count(), 216_001);
        assert!((s.gravity() - 9.800898).abs() < 5e-7);
        assert!((s.accel_sigma_mps2 * 60f64.sqrt() - 7.6e-4).abs() < 1e-5);
        s.validate().unwrap();
    }

    #[test]
    fn truth_paths() {
        assert_eq!(
            truth_path_for(Path::new("a/run.csv")),
            PathBuf::from("a/run.truth.json")
        );
        assert_eq!(
            truth_path_for(Path::new("run.CSV")),
            PathBuf::from("run.truth.json")
        );
        assert_eq!(
            truth_path_for(Path::new("run.dat")),
            PathBuf::from("run.dat.truth.json")
        );
    }

    #[test]
    fn sample_times_and_count() {
        let mut s = Scenario::paper().without_noise();
        s.hours = 0.01;
        s.rate_s = 0.5;
        let sim = simulate(&s);
        assert_eq!(sim.samples.len(), 73);
        assert_eq!(sim.samples[72].t_s, 36.0);
        assert_eq!(sim.samples[0].specific_force_mps2, [0.0, 0.0, s.gravity()]);
    }
}
