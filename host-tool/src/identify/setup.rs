//! The run's set-up as uncertain parameters: what the 1σ of a coefficient must carry besides the
//! noise (docs/model.md, "Set-up parameters").
//!
//! A recording states its set-up — the platform's start attitude (level and north), the latitude,
//! the recorder's time scale, gravity — as if exactly known. None is:
//! - **start attitude**: levelling leaves arcseconds of tilt, a gyrocompass alignment tens of
//!   arcseconds of azimuth. The angles are states of the filter, so this prior is *estimated*
//!   with the data (`Prepared::alignment_sigma`); [`Uncertainty`] reports what it adds against
//!   a start known to 0.2″ (the noise-only 1σ, the one the Cramér–Rao bound is compared with).
//! - **latitude, clock rate, gravity**: not states of the filter. Each is marginalised to first
//!   order: their signature through the fit's own linearised filter ([`super::knob_signature`])
//!   gives the coefficients' sensitivity `S = ∂ĉ/∂φ`, and the gradient and Gauss–Newton
//!   curvature of −2 ln p(y) (the data's own information about φ); the posterior variance
//!   `v = 1/(1/σ_prior² + c/2)` (c the curvature) then adds `S v Sᵀ` to the covariance — a
//!   Schmidt (consider) term where the data say nothing, shrunk where they do.
//! - **daily tilt of the apparent vertical** (a building's thermal tilt): a 24-h rotation of
//!   the measured gravity direction, too small to detect at this noise; a pure consider term,
//!   `S σ² Sᵀ`, S from the same replay (its four components are offsets of the measurements).
//! - **daily drift** (a laboratory's thermal cycle reaching the gyros): a drift at the solar day,
//!   which one run of a few days hardly separates from the coefficients (the platform turns with
//!   the sidereal day), and a **drift trend** (its slower temperature changes, the gyros'
//!   run-in), which a day-long run hardly separates from them either: marginalised at a physical
//!   prior ([`super::slow_drift`]).
//!
//! The total covariance is the fit's (start attitude estimated) plus these terms.

use anyhow::Context as _;
use estimator_core::effects::Effect;
use estimator_core::frames::Attitude;
use estimator_core::model::ANGLES;
use estimator_core::Site;
use nalgebra::{DMatrix, DVector, Vector3};
use serde::Serialize;

use super::knob_signature::{knob_signature, Offset};
use super::slow_drift::{marginalised, SlowDrift};
use super::smoother::final_covariance;
use super::{
    build_model, gauss_newton_final, neg2_log_evidence, start_prior, Config, Identification,
    Prepared,
};
use crate::diagnose::score::Signature;

/// Radians per arcsecond.
pub const RAD_PER_ARCSEC: f64 = std::f64::consts::PI / (180.0 * 3600.0);

/// Priors of the set-up (1σ each); `driftid` options `--alignment-arcsec`,
/// `--latitude-sigma-deg`, `--clock-sigma-ppm`, `--gravity-sigma-ppm`, `--vertical-tilt-arcsec`,
/// `--daily-drift-deg-h`, `--drift-trend-deg-h-per-day`, `--temp-drift-deg-h-per-c`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SetupPriors {
    /// Start tilt about each level axis, arcsec: a platform levelled on its accelerometers is
    /// level to their bias over g (1e-4 m/s² / g ≈ 2″); 5″ allows for the levelling loop.
    pub tilt_arcsec: f64,
    /// Start azimuth, arcsec: a gyrocompass alignment's error is the east drift over the
    /// horizontal Earth rate (1e-3 deg/h over 11.7 deg/h at 39° ≈ 18″); 30″ ("tens of arcseconds").
    pub azimuth_arcsec: f64,
    /// Latitude 1σ, deg; `None`: from the digits the latitude is written with (a uniform error
    /// of half the last digit, unit/√12), at least [`MIN_LATITUDE_SIGMA_DEG`].
    pub latitude_sigma_deg: Option<f64>,
    /// Clock rate 1σ, ppm: a logger stamping from an ordinary quartz crystal (±20 ppm at 25 °C,
    /// a few ppm of ageing and temperature in a laboratory). A disciplined clock: 1.
    pub clock_sigma_ppm: f64,
    /// Gravity 1σ, ppm of g: normal gravity or a value from a map misses altitude (0.3 ppm/m) and
    /// the local anomaly (tens of ppm).
    pub gravity_sigma_ppm: f64,
    /// Daily tilt of the apparent vertical, 1σ of each of its four components (east and north,
    /// in phase and in quadrature with the day), arcsec: a building's thermal tilt.
    pub vertical_tilt_arcsec: f64,
    /// Period of that tilt, h (a solar day).
    pub vertical_tilt_period_h: f64,
    /// A gyro drift that follows the solar day, 1σ of each of its six components (x, y, z; in
    /// phase and in quadrature with the day), deg/h: a laboratory's daily thermal cycle that
    /// reaches the gyros when no temperature is recorded. An air-conditioned room swings by
    /// about ±1 °C a day; the platform's thermal control passes some ±0.15 °C to the gyros; an
    /// electrostatic gyro's drift moves by ~0.002 deg/h per °C (the catalog's `temp-drift`
    /// examples span 0.001–0.003): 3e-4 deg/h.
    pub daily_drift_deg_h: f64,
    /// A gyro drift that changes steadily over the run, 1σ of each axis' change over a day,
    /// deg/h: the laboratory's slower temperature changes (its ±1 °C over days reaching the gyros
    /// as the daily cycle does, ±0.15 °C, at ~0.002 deg/h per °C) and the gyros' run-in: the daily
    /// drift's size, 3e-4 deg/h, in a day.
    pub drift_trend_deg_h_per_day: f64,
    /// A gyro drift proportional to the recorded temperature's deviation, 1σ per axis, deg/h per
    /// °C: an electrostatic gyro's drift moves by ~0.002 deg/h per °C (the figure the daily
    /// drift's and the trend's priors are built on). Carried only where the recording's
    /// temperature varies.
    pub temp_drift_deg_h_per_c: f64,
    /// Whether the latitude's, the clock rate's and the gravity's priors are the tool's defaults
    /// (an assumption the run rests on) rather than the user's statement.
    #[serde(skip)]
    pub assumed: [bool; 3],
}

/// Smallest default latitude 1σ, deg (≈ 10 m: a site's position is known at least that well).
pub const MIN_LATITUDE_SIGMA_DEG: f64 = 1e-4;

impl Default for SetupPriors {
    fn default() -> Self {
        SetupPriors {
            tilt_arcsec: 5.0,
            azimuth_arcsec: 30.0,
            latitude_sigma_deg: None,
            clock_sigma_ppm: 20.0,
            gravity_sigma_ppm: 30.0,
            vertical_tilt_arcsec: 1.0,
            vertical_tilt_period_h: 24.0,
            daily_drift_deg_h: 3e-4,
            drift_trend_deg_h_per_day: 3e-4,
            temp_drift_deg_h_per_c: 2e-3,
            assumed: [true; 3],
        }
    }
}

impl SetupPriors {
    /// The start attitude prior in the run's chart, rad: two tilts and the azimuth for a level
    /// start in the ENU chart; from any other start the small rotation mixes the three Euler
    /// angles, so each gets the larger.
    pub fn alignment_sigma(&self, level_enu: bool) -> [f64; 3] {
        let (t, a) = (
            self.tilt_arcsec * RAD_PER_ARCSEC,
            self.azimuth_arcsec * RAD_PER_ARCSEC,
        );
        if level_enu {
            [t, t, a]
        } else {
            [t.max(a); 3]
        }
    }

    /// The latitude 1σ for a latitude written as `latitude_deg`, deg.
    pub fn latitude_sigma(&self, latitude_deg: f64) -> f64 {
        self.latitude_sigma_deg
            .unwrap_or_else(|| written_precision(latitude_deg).max(MIN_LATITUDE_SIGMA_DEG))
    }
}

/// 1σ of a uniform rounding error of the last digit of `x` as Rust writes it shortest
/// (39.1 → 0.1/√12).
pub fn written_precision(x: f64) -> f64 {
    10f64.powi(-written_decimals(x)) / 12f64.sqrt()
}

/// The decimals `x` is written with: the fewest that give it back to 1e-9 (a latitude that went
/// through radians, −30.3 → −30.299999999999997, is still "−30.3": taken as 15 decimals it was
/// known to 1e-4°, and a run 0.03° off it was trusted 47σ off). At most 12.
fn written_decimals(x: f64) -> i32 {
    (0..12)
        .find(|&d| {
            let scale = 10f64.powi(d);
            ((x * scale).round() / scale - x).abs() <= 1e-9
        })
        .unwrap_or(12)
}

/// What one set-up parameter adds to the coefficients' uncertainty.
#[derive(Clone, Debug, Serialize)]
pub struct Contribution {
    /// `start attitude`, `latitude`, `clock rate`, `gravity`, `vertical tilt`, `daily drift`,
    /// `drift trend` or `thermal drift`.
    pub source: &'static str,
    /// The prior, in words with its unit.
    pub prior: String,
    /// 1σ the data alone give the parameter, in the prior's unit (`None`: not estimated, or the
    /// data say nothing).
    pub data_sigma: Option<f64>,
    /// Posterior 1σ used, in the prior's unit.
    pub posterior_sigma: f64,
    /// For a knob, its posterior 1σ with the slow drifts free, where that is wider (a trend the
    /// data cannot rule out bends the latitude's signature): what its share of the coefficients'
    /// 1σ is computed with ([`super::slow_drift::DriftReplay::knobs_with_drifts`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_drifts_free: Option<f64>,
    /// Where prior and data together put the parameter against the stated value, in the prior's
    /// unit (`None` where not estimated).
    pub offset: Option<f64>,
    /// Hard half-width of the stated value, where it has one (its written digits).
    pub bound: Option<f64>,
    /// The stated value and its unit (`latitude` 39.1 deg, …), where there is one.
    pub stated: Option<(f64, &'static str)>,
    /// 1σ this source adds to each parameter of the model (state order after the angles).
    pub sigma: Vec<f64>,
    /// The covariance it adds.
    #[serde(skip)]
    pub cov: DMatrix<f64>,
    /// For a slow drift: carried at a size the data asked for, above its prior (a drift the data
    /// see, not only one they cannot rule out).
    #[serde(skip)]
    pub sized_by_data: bool,
}

impl Contribution {
    /// The 1σ of a knob's estimate that this run supports: with the slow drifts free where that
    /// is wider (what its share of the coefficients' 1σ is computed with). The posterior alone
    /// holds the drifts at zero: on 16 of 40 runs of 36–48 h with the set-up drawn from its
    /// priors the latitude it gave was 7–18 of its 1σ (0.003°) off the truth; all 40 were within
    /// 2.6 of this one (0.02°).
    pub fn knob_sigma(&self) -> f64 {
        self.sigma_drifts_free.unwrap_or(self.posterior_sigma)
    }

    pub(crate) fn new(source: &'static str, prior: String, cov: DMatrix<f64>) -> Self {
        Contribution {
            source,
            prior,
            data_sigma: None,
            posterior_sigma: f64::NAN,
            sigma_drifts_free: None,
            sized_by_data: false,
            offset: None,
            bound: None,
            stated: None,
            sigma: (0..cov.nrows())
                .map(|k| cov[(k, k)].max(0.0).sqrt())
                .collect(),
            cov,
        }
    }
}

/// The coefficients' uncertainty with the set-up's.
#[derive(Clone, Debug, Serialize)]
pub struct Uncertainty {
    /// 1σ with the set-up exactly as stated (start attitude to 0.2″): noise only.
    pub noise_sigma: Vec<f64>,
    /// 1σ with every set-up prior: the headline.
    pub total_sigma: Vec<f64>,
    /// Each source's share.
    pub contributions: Vec<Contribution>,
    /// The total covariance of the parameters.
    #[serde(skip)]
    pub total_cov: DMatrix<f64>,
    /// The set-up's share of it beyond the fit's own covariance (latitude, clock rate, gravity,
    /// the vertical's daily tilt, the slow drifts; the start attitude is in the fit): what a
    /// joint fit of several runs marginalises from each ([`super::joint::RunSetup`]).
    #[serde(skip)]
    pub setup_cov: DMatrix<f64>,
    /// Where prior and data put the latitude (deg), clock rate (ppm) and gravity (ppm) against
    /// the stated values: [`settle`] refits there.
    pub setup_shift: [f64; 3],
    /// The data against the stated set-up (`None` for a single pass).
    pub setup_check: Option<SetupCheck>,
    /// 1σ from averaging over the plausible explanations (empty until added).
    pub model_spread: Vec<f64>,
    /// The data's quadratic model of latitude, clock rate and gravity about the stated set-up
    /// (`None` for a single pass): what [`super::misstated`] weighs a misstated set-up with.
    #[serde(skip)]
    pub knobs: Option<KnobModel>,
    /// How far marginalising the slow drifts (daily, trend) at their priors moves the parameters
    /// (state order after the angles; empty for a single pass): [`settle`] applies it (and a joint
    /// fit again to each relinearised run, [`super::joint::RunSetup::shift`]).
    #[serde(skip)]
    pub drift_shift: Vec<f64>,
}

/// −2 ln p(y) to second order in the knobs (latitude, clock rate, gravity) about the stated
/// set-up, in units `u = δ/h` of each knob's prior 1σ `h`: `f0 + gᵀu + ½ uᵀHu`, and the
/// coefficients' sensitivity `∂ĉ/∂u`.
#[derive(Clone, Debug)]
pub struct KnobModel {
    /// −2 ln p(y) at the stated set-up.
    pub f0: f64,
    /// Gradient g.
    pub grad: DVector<f64>,
    /// Hessian H (Gauss–Newton, clamped positive semi-definite).
    pub hess: DMatrix<f64>,
    /// Sensitivity of the parameters (after the angles) per unit u, one column per knob.
    pub sens: DMatrix<f64>,
    /// The unit of each knob, its prior 1σ h (deg, ppm, ppm; 0: not marginalised).
    pub unit: [f64; 3],
}

impl Uncertainty {
    /// The source that adds most to parameter `k` (`noise` when none adds as much as the noise).
    pub fn dominant(&self, k: usize) -> &'static str {
        let best = self
            .contributions
            .iter()
            .max_by(|a, b| a.sigma[k].total_cmp(&b.sigma[k]));
        let spread = self.model_spread.get(k).copied().unwrap_or(0.0);
        match best {
            _ if spread > self.noise_sigma[k] && best.is_none_or(|c| spread > c.sigma[k]) => {
                "other models"
            }
            Some(c) if c.sigma[k] > self.noise_sigma[k] => c.source,
            _ => "noise",
        }
    }

    /// Why the result is not trusted on the set-up's account: the data contradict the stated
    /// set-up ([`SetupCheck`]), or put a knob beyond what its written value allows by more than
    /// 3 of the 1σ the run supports ([`Contribution::knob_sigma`]: held to the posterior with
    /// the slow drifts at zero, 7 of 40 runs of 24–48 h with the set-up drawn from its priors had
    /// their latitude "outside its digits", the truth within them).
    pub fn untrusted_reasons(&self) -> Vec<String> {
        let mut out = vec![];
        for k in &self.contributions {
            let (Some(b), Some(o), Some((v, unit))) = (k.bound, k.offset, k.stated) else {
                continue;
            };
            if o.abs() - 3.0 * k.knob_sigma() > b {
                out.push(format!(
                    "the data put the {} at {} {unit}, outside what the stated {} allows (±{}): either it is wrong or an \
                     effect with a similar signature is present (a recorder clock's rate, a drift trend) — `driftid diagnose` \
                     weighs the explanations; give the {} with the digits it is known to",
                    k.source,
                    crate::format::pm(v + o, k.knob_sigma()),
                    crate::format::sig(v, 9),
                    crate::format::sig(b, 2),
                    k.source
                ));
            }
        }
        let Some(c) = self.setup_check.filter(|c| c.p_value < CONTRADICTION_P) else {
            return out;
        };
        let moved: Vec<String> = self.contributions[1..4]
            .iter()
            .filter_map(|k| {
                let (v, unit) = k.stated?;
                Some(format!(
                    "{} {} {unit} (stated {})",
                    k.source,
                    // With the 1σ the knob is printed with everywhere ([`Contribution::knob_sigma`]):
                    // the same run printed the latitude "40.723 ± 0.021" in the digits check
                    // above and "40.7231 ± 0.0019" here.
                    crate::format::pm(v + k.offset?, k.knob_sigma()),
                    crate::format::sig(v, 9)
                ))
            })
            .collect();
        out.push(format!(
            "the data contradict the stated set-up and its priors (χ² = {:.1} on {} dof, p = {}): prior and data together put it at {}; \
             either the set-up is wrong or an effect with a similar signature is present — `driftid diagnose` weighs the explanations",
            c.chi2,
            c.dof,
            crate::format::sci(c.p_value),
            moved.join(", ")
        ));
        out
    }

    /// Adds the model-averaging spread ([`crate::diagnose::alternatives`]) to the total, in
    /// place of any spread added before (the alternatives weighed again with more rivals).
    pub fn add_model_spread(&mut self, spread: &[f64]) {
        for (k, s) in spread.iter().enumerate() {
            let before = self.model_spread.get(k).copied().unwrap_or(0.0);
            self.total_cov[(k, k)] += s * s - before * before;
            self.total_sigma[k] = self.total_cov[(k, k)].max(0.0).sqrt();
        }
        self.model_spread = spread.to_vec();
    }

    /// Total over noise-only 1σ of parameter `k`.
    pub fn ratio(&self, k: usize) -> f64 {
        self.total_sigma[k] / self.noise_sigma[k]
    }

    /// No set-up uncertainty: the fit's own covariance (the single pass, or `--setup exact`).
    pub fn exact(cov: &DMatrix<f64>) -> Self {
        let s: Vec<f64> = (0..cov.nrows()).map(|k| cov[(k, k)].sqrt()).collect();
        Uncertainty {
            noise_sigma: s.clone(),
            total_sigma: s,
            contributions: vec![],
            total_cov: cov.clone(),
            setup_cov: DMatrix::zeros(cov.nrows(), cov.ncols()),
            setup_shift: [0.0; 3],
            setup_check: None,
            model_spread: vec![],
            knobs: None,
            drift_shift: vec![],
        }
    }
}

/// `prep` at another latitude: the site moved (gravity moves with it when it was normal
/// gravity, and stays when given or measured) and the start's attitude kept, re-expressed in the
/// chart that start calls for there (a chart's angles depend on the latitude).
pub fn at_latitude(prep: &Prepared, lat_deg: f64) -> Prepared {
    at_latitude_with(prep, lat_deg, normal_gravity_at_site(prep))
}

/// Whether `prep`'s gravity is the normal gravity of its latitude (and so moves with it).
pub(crate) fn normal_gravity_at_site(prep: &Prepared) -> bool {
    (prep.site.gravity_mps2 - estimator_core::frames::normal_gravity(prep.site.latitude_rad)).abs()
        < 1e-12
}

/// The gravity `prep`'s measurements show, the site at latitude `lat_deg`: the mean over the
/// filter-period means of |A|, each lifted by the curvature of its window that the model adds
/// (the mean of the turning A is shorter than g by ½·Var(t)·ω_e²·cos²L·g,
/// [`estimator_core::Model::measurement`]). At rest |A| is g whatever the attitude, so this is
/// the gravity a fit without accelerometer effects asks for, to ~0.02 ppm on a 60-h run.
pub fn measured_gravity(prep: &Prepared, lat_deg: f64) -> f64 {
    let w2_cos2 = (estimator_core::units::EARTH_RATE_RADPS * lat_deg.to_radians().cos()).powi(2);
    let n = prep.measurements.len().max(1) as f64;
    prep.measurements
        .iter()
        .map(|m| Vector3::from(m.specific_force).norm() / (1.0 - 0.5 * m.time_var_s2 * w2_cos2))
        .sum::<f64>()
        / n
}

/// `prep` at latitude `lat_deg` with the gravity its measurements show ([`measured_gravity`]).
pub fn at_latitude_measured(prep: &Prepared, lat_deg: f64) -> Prepared {
    let enu = prep.site.angles_to_enu(&prep.initial_angles);
    let mut site = Site::new(lat_deg, Some(measured_gravity(prep, lat_deg)));
    site.chart = site.chart_for_start(&enu);
    in_site(prep, site, &enu)
}

/// [`at_latitude`], gravity moving with the latitude (`derived`) or kept.
pub fn at_latitude_with(prep: &Prepared, lat_deg: f64, derived: bool) -> Prepared {
    let enu = prep.site.angles_to_enu(&prep.initial_angles);
    let mut site = Site::new(lat_deg, (!derived).then_some(prep.site.gravity_mps2));
    site.chart = site.chart_for_start(&enu);
    in_site(prep, site, &enu)
}

/// The site at latitude `lat_deg` in the chart `prep` has (gravity as in [`at_latitude`]) and
/// `prep`'s start re-expressed there: a set-up moved by a prior σ for a refit warm-started from
/// the stated fit, whose trajectory's angles are in that chart. Choosing the chart anew switched
/// it where a start sits on the charts' border (a level start at exactly 30° S), and the refit
/// started 60° off and diverged.
fn latitude_in_chart(prep: &Prepared, lat_deg: f64) -> (Site, [f64; 3]) {
    let enu = prep.site.angles_to_enu(&prep.initial_angles);
    let derived = normal_gravity_at_site(prep);
    let mut site = Site::new(lat_deg, (!derived).then_some(prep.site.gravity_mps2));
    site.chart = prep.site.chart;
    (site, site.angles_to_chart(&enu))
}

/// `prep` at `site`, its start (ENU angles `enu`) re-expressed in the site's chart.
fn in_site(prep: &Prepared, site: Site, enu: &[f64; 3]) -> Prepared {
    let mut p = prep.clone();
    p.initial_angles = site.angles_to_chart(enu);
    p.site = site;
    p
}

/// The factor a clock running fast by `ppm` puts on the time stamps (they are divided by
/// 1 + ppm·1e-6).
pub(crate) fn clock_scale(ppm: f64) -> f64 {
    1.0 / (1.0 + ppm * 1e-6)
}

/// The site and start of `prep` with the set-up moved by `d` (latitude deg, clock ppm, gravity
/// ppm; the clock moves the time stamps, not these), in its chart: [`moved`] without the
/// measurements.
pub(crate) fn moved_site(prep: &Prepared, d: [f64; 3]) -> (Site, [f64; 3]) {
    let lat_deg = prep.site.latitude_rad.to_degrees();
    let (mut site, angles) = if d[0] != 0.0 {
        latitude_in_chart(prep, lat_deg + d[0])
    } else {
        (prep.site, prep.initial_angles)
    };
    if d[2] != 0.0 {
        site.gravity_mps2 *= 1.0 + d[2] * 1e-6;
    }
    (site, angles)
}

/// Gauss–Newton passes of a set-up refit at most ([`refit`]).
const REFIT_ITERATIONS: usize = 3;

/// A warm-started refit of `effects` on `p`: −2 ln p(y) and the parameters (after the angles).
/// Gauss–Newton passes about the converged fit of the stated set-up, until converged (at most
/// [`REFIT_ITERATIONS`]): `p` differs from it by one prior σ of a knob, often one pass.
pub(crate) fn refit(
    p: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
) -> anyhow::Result<(f64, DVector<f64>)> {
    let model = build_model(p.site, effects, cfg)?;
    let (x0, p0) = start_prior(&model, p, &p.start_sigma());
    let passes = |max: usize| {
        gauss_newton_final(
            &model,
            &p.measurements,
            id.trajectory.clone(),
            &x0,
            &p0,
            1,
            max,
        )
    };
    // A later pass can diverge where the moved set-up's linearisation is poor (a latitude
    // written "30": the third pass's covariance blew up): then the one pass stands.
    let fit = passes(REFIT_ITERATIONS).or_else(|_| passes(1))?;
    let last = fit.states.last().context("no states")?;
    Ok((
        neg2_log_evidence(&fit.innovations),
        last.rows(ANGLES, model.dim() - ANGLES).into_owned(),
    ))
}

/// p-value below which the data contradict the stated set-up: a clean run crosses it once in
/// ~16 000 (a normal deviate beyond 4σ).
pub const CONTRADICTION_P: f64 = 6.3e-5;

/// How well the data agree with the stated set-up and its priors: the score of the knobs at the
/// stated values against its spread, `χ² = gᵀ [H (H + 2)]⁺ g` in units of the priors (g, H: the
/// gradient and Hessian of −2 ln p(y); under the priors Var g = H² + 2H), on rank(H) dof.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct SetupCheck {
    /// The statistic.
    pub chi2: f64,
    /// Its degrees of freedom.
    pub dof: usize,
    /// Its p-value.
    pub p_value: f64,
}

/// One set-up parameter that is not a state of the filter.
struct Knob {
    /// Hard half-width of the stated value where it has one (a latitude written to 0.1° lies
    /// within ±0.05° of the truth).
    bound: Option<f64>,
    source: &'static str,
    unit: &'static str,
    prior: String,
    sigma_prior: f64,
    stated: f64,
}

/// `prep` with the set-up moved by `d` (latitude deg, clock ppm, gravity ppm), in its chart.
pub(crate) fn moved(prep: &Prepared, d: [f64; 3]) -> Prepared {
    let mut p = prep.clone();
    (p.site, p.initial_angles) = moved_site(prep, d);
    if d[1] != 0.0 {
        let k = clock_scale(d[1]);
        for m in &mut p.measurements {
            m.t_s *= k;
            m.time_var_s2 *= k * k;
        }
    }
    p
}

/// The knobs marginalised together (see the module docs): their signature gives the gradient
/// and Hessian of −2 ln p(y) and the coefficients' sensitivities; with the prior, the posterior
/// of the knobs is Gaussian to second order, and its covariance V adds `S V Sᵀ` to the
/// coefficients'. In units of each knob's prior 1σ.
struct Marginal {
    /// Per knob its contribution (the marginal share `S_k V_kk S_kᵀ`; the total uses all of V).
    contributions: Vec<Contribution>,
    /// The covariance the knobs add together.
    cov: DMatrix<f64>,
    /// The knobs' posterior offset from the stated values, in their units.
    shift: [f64; 3],
    /// The data against the stated set-up.
    check: SetupCheck,
    /// The quadratic model it was built from.
    model: KnobModel,
}

/// −2 ln p(y) to second order about the stated set-up, `f0 + gᵀu + ½ uᵀHu`, and the
/// coefficients' sensitivity `∂ĉ/∂u` (`n` of them), in units of each knob's prior 1σ `h`
/// (`u = δ/h`; a knob with h = 0 is held: zeros), from the knobs' signature through the fit's
/// own linearised filter ([`super::knob_signature`], per unit of each knob): g = −2 s,
/// H = 2 I, ∂ĉ/∂u = Ψ_N, each scaled by h.
fn quadratic(
    h: &[f64; 3],
    sig: &Signature,
    n: usize,
) -> (DVector<f64>, DMatrix<f64>, DMatrix<f64>) {
    let h = h.map(|v| if v > 0.0 { v } else { 0.0 });
    let grad = DVector::from_fn(3, |k, _| -2.0 * sig.score[k] * h[k]);
    let hess = DMatrix::from_fn(3, 3, |k, l| 2.0 * sig.info[(k, l)] * h[k] * h[l]);
    let sens = DMatrix::from_fn(n, 3, |i, k| sig.psi_final[(ANGLES + i, k)] * h[k]);
    (grad, hess, sens)
}

/// Which knobs are marginalised (a zero prior takes one as exact).
fn live(knobs: &[Knob; 3]) -> [bool; 3] {
    [0, 1, 2].map(|k| knobs[k].sigma_prior > 0.0)
}

/// Whether the data contradict the stated set-up and its priors: gᵀ(H(H+2))⁻¹g over the
/// eigendirections the data curve (`eig` of the data's Hessian, `grad` its gradient, both in
/// the priors' units), χ² on that many degrees of freedom.
fn setup_check(
    eig: &nalgebra::SymmetricEigen<f64, nalgebra::Dyn>,
    grad: &DVector<f64>,
) -> SetupCheck {
    let lmax = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
    let (mut chi2, mut dof) = (0.0, 0);
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l > 1e-6 * lmax.max(1e-6) {
            let gl = eig.eigenvectors.column(k).dot(grad);
            chi2 += gl * gl / (l * (l + 2.0));
            dof += 1;
        }
    }
    let p_value = if dof > 0 {
        crate::stats::chi2_sf(chi2, dof as f64)
    } else {
        1.0
    };
    SetupCheck { chi2, dof, p_value }
}

/// The knobs marginalised (see [`Marginal`]) about the fit whose −2 ln p(y) is `f0`, from their
/// signature `sig` through its filter (`n` coefficients).
fn marginalise(knobs: &[Knob; 3], f0: f64, sig: &Signature, n: usize) -> anyhow::Result<Marginal> {
    let h: [f64; 3] = [0, 1, 2].map(|k| knobs[k].sigma_prior);
    let (grad, hess, sens) = quadratic(&h, sig, n);
    // The data's curvature is a Gauss–Newton Hessian, positive semi-definite up to rounding.
    let eig = nalgebra::SymmetricEigen::new(hess.clone());
    let hess_psd = psd_part(&eig);
    let a = &hess_psd + DMatrix::identity(3, 3) * 2.0;
    let a_inv = a.try_inverse().context(
        "the set-up's posterior could not be formed from the data's response to the latitude, clock rate and gravity (not finite), so what they add to the 1σ is unknown; setting their priors to 0 (--latitude-sigma-deg 0 --clock-sigma-ppm 0 --gravity-sigma-ppm 0) takes them as exact",
    )?;
    let v = &a_inv * 2.0;
    let shift_u = -(&a_inv * &grad);
    let cov = &sens * &v * sens.transpose();
    let check = setup_check(&eig, &grad);
    let contributions = (0..3)
        .map(|k| {
            let kn = &knobs[k];
            let col = sens.column(k).into_owned();
            let mut c = Contribution::new(
                kn.source,
                kn.prior.clone(),
                &col * col.transpose() * v[(k, k)],
            );
            c.stated = Some((kn.stated, kn.unit));
            c.bound = kn.bound;
            c.posterior_sigma = v[(k, k)].sqrt() * h[k];
            let curv = hess_psd[(k, k)];
            if curv > 0.0 && h[k] > 0.0 {
                c.data_sigma = Some((2.0 / curv).sqrt() * h[k]);
            }
            if h[k] > 0.0 {
                c.offset = Some(shift_u[k] * h[k]);
            }
            c
        })
        .collect();
    Ok(Marginal {
        contributions,
        cov,
        shift: [0, 1, 2].map(|k| shift_u[k] * h[k]),
        check,
        model: KnobModel {
            f0,
            grad,
            hess: hess_psd,
            sens,
            unit: [h[0], h[1], h[2]],
        },
    })
}

/// A symmetric matrix from its eigendecomposition with the negative eigenvalues set to zero: a
/// Gauss–Newton curvature is positive semi-definite, finite differences leave it slightly less.
pub(crate) fn psd_part(eig: &nalgebra::SymmetricEigen<f64, nalgebra::Dyn>) -> DMatrix<f64> {
    &eig.eigenvectors
        * DMatrix::from_diagonal(&eig.eigenvalues.map(|l| l.max(0.0)))
        * eig.eigenvectors.transpose()
}

/// The daily tilt of the apparent vertical (four components: a rotation about east or north ×
/// cos or sin of its period) as offsets of the measurements per prior 1σ, to carry through the
/// fit's filter ([`knob_signature`]); none when its prior is zero.
fn vertical_tilt_offsets<'a>(
    prep: &'a Prepared,
    id: &'a Identification,
    priors: &SetupPriors,
) -> Vec<Offset<'a>> {
    let sigma = priors.vertical_tilt_arcsec * RAD_PER_ARCSEC;
    if sigma <= 0.0 || sigma.is_nan() {
        return vec![];
    }
    let omega = 2.0 * std::f64::consts::PI / (priors.vertical_tilt_period_h * 3600.0);
    let g = prep.site.gravity_mps2;
    let r = prep.site.chart_rotation();
    (0..4)
        .map(|c| -> Offset<'a> {
            Box::new(move |j| {
                let t = prep.measurements[j].t_s;
                let phase = if c % 2 == 0 {
                    (omega * t).cos()
                } else {
                    (omega * t).sin()
                };
                // δ × g0 for a rotation δ of the vertical about the east axis is (0, −δ g, 0),
                // about north (δ g, 0, 0), in ENU.
                let d = sigma * phase * g;
                let v0 = if c < 2 {
                    Vector3::new(0.0, -d, 0.0)
                } else {
                    Vector3::new(d, 0.0, 0.0)
                };
                let th = &id.trajectory[j + 1];
                Attitude::new(&Vector3::new(th[0], th[1], th[2])).specific_force(&(r * v0))
            })
        })
        .collect()
}

/// The daily tilt's consider term `Σ_c S_c S_cᵀ` from its columns of `sig` (after the knobs':
/// the coefficients' response per prior 1σ of each component).
fn vertical_tilt(sig: &Signature, n: usize, priors: &SetupPriors) -> Contribution {
    let mut cov = DMatrix::zeros(n, n);
    for c in 3..sig.psi_final.ncols() {
        let col = sig.psi_final.view((ANGLES, c), (n, 1));
        cov += col * col.transpose();
    }
    if sig.psi_final.ncols() == 3 {
        return Contribution::new("vertical tilt", "0".into(), cov);
    }
    let mut c = Contribution::new(
        "vertical tilt",
        format!(
            "{}″ per component, {} h period",
            priors.vertical_tilt_arcsec, priors.vertical_tilt_period_h
        ),
        cov,
    );
    c.posterior_sigma = priors.vertical_tilt_arcsec;
    c
}

/// The coefficients' uncertainty with the set-up priors of `cfg` (see the module docs). `id` is
/// the converged fit of `effects` on `prep`.
/// The set-up parameters that are not states of the filter, as `prep` states them and `priors`
/// weigh them: latitude, clock rate, gravity.
fn knobs(prep: &Prepared, priors: &SetupPriors) -> [Knob; 3] {
    let lat_deg = prep.site.latitude_rad.to_degrees();
    let lat_sigma = priors.latitude_sigma(lat_deg);
    [
        Knob {
            bound: priors
                .latitude_sigma_deg
                .is_none()
                .then(|| written_precision(lat_deg) * 12f64.sqrt() / 2.0)
                .filter(|b| *b >= MIN_LATITUDE_SIGMA_DEG),
            source: "latitude",
            unit: "deg",
            prior: format!("{} deg", crate::format::sig(lat_sigma, 2)),
            sigma_prior: lat_sigma,
            stated: (lat_deg * 1e9).round() / 1e9,
        },
        Knob {
            bound: None,
            source: "clock rate",
            unit: "ppm",
            prior: format!("{} ppm", crate::format::sig(priors.clock_sigma_ppm, 2)),
            sigma_prior: priors.clock_sigma_ppm,
            stated: 0.0,
        },
        Knob {
            bound: None,
            source: "gravity",
            unit: "ppm",
            prior: format!(
                "{} ppm of {} m/s^2",
                crate::format::sig(priors.gravity_sigma_ppm, 2),
                crate::format::sig(prep.site.gravity_mps2, 7)
            ),
            sigma_prior: priors.gravity_sigma_ppm,
            stated: 0.0,
        },
    ]
}

/// The knobs' quadratic model alone and the latitude's bound (its written digits): what a
/// misstated set-up is weighed with ([`crate::diagnose::misstated::within_priors`]), without
/// the terms [`uncertainty`] adds besides (the noise-only pass, the vertical tilt, the slow
/// drifts and their path through the knobs: a third of its time). `None` for a single pass.
pub(crate) fn knob_model(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
) -> anyhow::Result<Option<(KnobModel, Option<f64>)>> {
    if id.refined.is_none() {
        return Ok(None);
    }
    let knobs = knobs(prep, &cfg.setup);
    let f0 = neg2_log_evidence(&id.innovations);
    let (_, sig) = knob_signature(prep, effects, cfg, &id.trajectory, (live(&knobs), &[]))?;
    let marginal = marginalise(&knobs, f0, &sig, id.best().value.len())?;
    Ok(Some((marginal.model, knobs[0].bound)))
}

/// An [`Uncertainty`] with a key of what it was computed from ([`key`]): asked again for the
/// same effects, set-up, settings and fit, [`uncertainty_reusing`] hands it back instead of
/// refitting (`diagnose` assesses its starting model a second time when the ladder adds nothing:
/// 0.2 s of a clean 60-h run).
#[derive(Clone)]
pub struct Computed {
    key: u64,
    unc: Uncertainty,
    /// The misstatements weighed about the same fit with `unc`
    /// ([`crate::diagnose::misstated::weigh`]), where they were.
    misstated: Option<crate::diagnose::misstated::Weighed>,
    /// The model refitted where [`settle`] refits from the same fit ([`settling_fit`]), where
    /// it was.
    settling: Option<Identification>,
}

impl Computed {
    /// `unc`, computed by [`uncertainty`] from these arguments.
    pub fn new(
        effects: &[&dyn Effect],
        prep: &Prepared,
        cfg: &Config,
        id: &Identification,
        unc: Uncertainty,
    ) -> Self {
        Computed {
            key: key(effects, prep, cfg, id),
            unc,
            misstated: None,
            settling: None,
        }
    }

    /// Keeps the misstatements weighed from these arguments and the uncertainty
    /// ([`crate::diagnose::misstated::weigh`]): the refits of three set-ups and, where the
    /// latitude lies far, its profile.
    pub(crate) fn keep_misstated(&mut self, weighed: crate::diagnose::misstated::Weighed) {
        self.misstated = Some(weighed);
    }

    /// Keeps the model refitted where [`settle`] refits from these arguments ([`settling_fit`]).
    pub(crate) fn keep_settling(&mut self, fit: Identification) {
        self.settling = Some(fit);
    }

    /// The settling fit kept ([`Self::keep_settling`]) if it was made from these arguments.
    pub(crate) fn settling_for(
        &self,
        effects: &[&dyn Effect],
        prep: &Prepared,
        cfg: &Config,
        id: &Identification,
    ) -> Option<&Identification> {
        self.settling
            .as_ref()
            .filter(|_| self.key == key(effects, prep, cfg, id))
    }

    /// The misstatements kept ([`Self::keep_misstated`]) if they were weighed from these
    /// arguments.
    pub(crate) fn misstated_for(
        &self,
        effects: &[&dyn Effect],
        prep: &Prepared,
        cfg: &Config,
        id: &Identification,
    ) -> Option<&crate::diagnose::misstated::Weighed> {
        self.misstated
            .as_ref()
            .filter(|_| self.key == key(effects, prep, cfg, id))
    }
}

/// A hash of everything [`uncertainty`] reads: the effects ([`super::memo::hash_effects`]), the set-up (site, start and
/// its priors, every measurement, the noise floor), the settings, and the fit bit for bit (its
/// parameters, estimate, covariance, evidence and trajectory's end).
fn key(effects: &[&dyn Effect], prep: &Prepared, cfg: &Config, id: &Identification) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    super::memo::hash_prep(&mut h, prep);
    let mut put = |vs: &[f64]| vs.iter().for_each(|v| v.to_bits().hash(&mut h));
    let est = id.best();
    put(&est.value);
    put(est.cov.as_slice());
    put(&[neg2_log_evidence(&id.innovations), id.final_time_h]);
    if let Some(last) = id.trajectory.last() {
        put(last.as_slice());
    }
    super::memo::hash_effects(&mut h, effects);
    for p in &id.params {
        p.name.hash(&mut h);
    }
    format!("{cfg:?}").hash(&mut h);
    id.trajectory.len().hash(&mut h);
    h.finish()
}

/// [`uncertainty`], or `known`'s when it was computed from the same arguments.
pub fn uncertainty_reusing(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
    known: Option<&Computed>,
) -> anyhow::Result<Uncertainty> {
    match known {
        Some(k) if k.key == key(effects, prep, cfg, id) => Ok(k.unc.clone()),
        _ => uncertainty(effects, prep, cfg, id),
    }
}

pub fn uncertainty(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
) -> anyhow::Result<Uncertainty> {
    let est = id.best();
    let Some(_) = id.refined.as_ref() else {
        return Ok(Uncertainty::exact(&est.cov));
    };
    let priors = cfg.setup;
    let model = build_model(prep.site, effects, cfg)?;
    let n = model.dim() - ANGLES;
    let f0 = neg2_log_evidence(&id.innovations);
    // Noise only: the same pass with the start attitude known to 0.2″.
    // Before the others, not beside them: three passes at once held 25 MB more at their peak
    // (a 3-h run at `--period-s 1`), past what the memory budget's slack allows.
    let noise_cov = {
        let (x0, p0) = start_prior(&model, prep, &prep.initial_angle_sigma);
        final_covariance(&model, &prep.measurements, &id.trajectory, &x0, &p0)?
            .view((ANGLES, ANGLES), (n, n))
            .into_owned()
    };
    let knobs = knobs(prep, &priors);
    let offsets = vertical_tilt_offsets(prep, id, &priors);
    // The knobs' replay beside the slow drifts and then their replay with the knobs (which
    // needs only which knobs are live, not the knobs' model).
    let (signature, drifts) = rayon::join(
        || knob_signature(prep, effects, cfg, &id.trajectory, (live(&knobs), &offsets)),
        || -> anyhow::Result<_> {
            let drifts = slow_drifts(effects, prep, cfg, id)?;
            let replay = super::slow_drift::drift_replay(
                &drifts.carried,
                effects,
                prep,
                cfg,
                id,
                live(&knobs),
            )?;
            Ok((drifts, replay))
        },
    );
    let (_, sig) = signature?;
    let mut marginal = marginalise(&knobs, f0, &sig, n)?;
    let tilt = vertical_tilt(&sig, n, &priors);
    let (drifts, replay) = drifts?;
    if let Some(r) = replay {
        with_drift_path(&mut marginal, &r);
    }
    // The start attitude is estimated in the fit: what it adds is the fit's covariance less the
    // noise-only one.
    let start = Contribution::new(
        "start attitude",
        format!(
            "tilt {}″, azimuth {}″",
            priors.tilt_arcsec, priors.azimuth_arcsec
        ),
        &est.cov - &noise_cov,
    );
    let mut contributions = vec![start];
    contributions.extend(marginal.contributions);
    contributions.push(tilt);
    contributions.extend(drifts.contributions);
    // The knobs' joint covariance (their correlations kept), then the tilt's and the slow
    // drifts' (each marginalised on its own: their sum is conservative where they correlate).
    let setup_cov = contributions[4..]
        .iter()
        .fold(marginal.cov.clone(), |acc, c| acc + &c.cov);
    let total_cov = &noise_cov + &contributions[0].cov + &setup_cov;
    Ok(Uncertainty {
        noise_sigma: (0..n).map(|k| noise_cov[(k, k)].sqrt()).collect(),
        total_sigma: (0..n).map(|k| total_cov[(k, k)].sqrt()).collect(),
        contributions,
        total_cov,
        setup_cov,
        setup_shift: marginal.shift,
        setup_check: Some(marginal.check),
        model_spread: vec![],
        knobs: Some(marginal.model),
        drift_shift: drifts.shift,
    })
}

/// The knobs' covariance and shares with the carried slow drifts free
/// ([`super::slow_drift::DriftReplay::knobs_with_drifts`]): the path of a drift through the latitude, clock
/// rate and gravity into the coefficients, which each term alone misses. Their estimate, the
/// check and the quadratic model the misstated set-up is weighed with stay the stated model's.
fn with_drift_path(marginal: &mut Marginal, replay: &super::slow_drift::DriftReplay) {
    let Some((hess, sens)) = replay.knobs_with_drifts(&marginal.model) else {
        return;
    };
    let Some(a_inv) = (&hess + DMatrix::identity(3, 3) * 2.0).try_inverse() else {
        return;
    };
    let v = a_inv * 2.0;
    marginal.cov = &sens * &v * sens.transpose();
    for (k, c) in marginal.contributions.iter_mut().enumerate() {
        let col = sens.column(k).into_owned();
        let cov = &col * col.transpose() * v[(k, k)];
        c.sigma = (0..cov.nrows())
            .map(|i| cov[(i, i)].max(0.0).sqrt())
            .collect();
        c.cov = cov;
        let free = v[(k, k)].sqrt() * marginal.model.unit[k];
        if free > 1.01 * c.posterior_sigma {
            c.sigma_drifts_free = Some(free);
        }
    }
}

/// The slow drifts marginalised about a fit ([`slow_drifts`]).
struct SlowDrifts {
    /// Each one's contribution, in [`SlowDrift::ALL`]'s order (those that apply).
    contributions: Vec<Contribution>,
    /// Where they move the parameters (the daily drift's shift only).
    shift: Vec<f64>,
    /// Those carried, at their sizes.
    carried: Vec<(SlowDrift, f64)>,
}

/// The slow drifts ([`SlowDrift::ALL`]) marginalised about the fit: their contributions and the
/// shift of the daily drift. The trend's covariance is carried but its shift is not applied: on
/// a daily sine of 1e-3 deg/h outside both priors (60 h at 1 s) the trend took up part of it and
/// its shift moved DZx to 3.0–3.8 total σ off, trusted (2.0–2.1 without it).
fn slow_drifts(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
) -> anyhow::Result<SlowDrifts> {
    slow_drifts_of(&SlowDrift::ALL, effects, prep, cfg, id)
}

/// The shift of the coefficients where the slow drifts' priors and the data put them
/// ([`SlowDrifts::shift`]): [`slow_drifts`] of the kinds that shift the estimate only, the others'
/// filter passes (their covariance is not asked for) not run.
fn slow_drift_shift(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
) -> anyhow::Result<Vec<f64>> {
    let shifting: Vec<SlowDrift> = SlowDrift::ALL
        .into_iter()
        .filter(|k| k.shifts_the_estimate())
        .collect();
    Ok(slow_drifts_of(&shifting, effects, prep, cfg, id)?.shift)
}

/// [`slow_drifts`] of the `kinds` given.
fn slow_drifts_of(
    kinds: &[SlowDrift],
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
) -> anyhow::Result<SlowDrifts> {
    let n = id.best().value.len();
    let mut out = SlowDrifts {
        contributions: vec![],
        shift: vec![0.0; n],
        carried: vec![],
    };
    for &kind in kinds.iter().filter(|k| k.applies(prep)) {
        let m = marginalised(kind, effects, prep, cfg, id)?;
        if kind.shifts_the_estimate() {
            for (a, b) in out.shift.iter_mut().zip(&m.shift) {
                *a += b;
            }
        }
        if let Some(size) = m.size {
            out.carried.push((kind, size));
        }
        out.contributions.push(m.contribution);
    }
    Ok(out)
}

/// A fit at the set-up's posterior: the identification, its measurements and the uncertainty.
pub struct Settled {
    /// Measurements with the set-up where prior and data put it.
    pub prep: Prepared,
    /// The fit there.
    pub id: Identification,
    /// The uncertainty (computed about the stated set-up: the covariances barely move).
    pub unc: Uncertainty,
    /// The refit at the set-up's posterior ([`settling_refit`]) as [`refit`] returns one —
    /// −2 ln p(y) and the parameters after the angles — also where it was not adopted (it did
    /// not follow the knobs' linear model); `None` where none was made or it failed. The
    /// misstatements weigh the stated set-up with its priors on it
    /// ([`crate::diagnose::misstated::Refitted::weigh`]).
    pub at_posterior: Option<(f64, DVector<f64>)>,
}

/// Where the knobs' posterior lies more than this many posterior 1σ from the stated set-up, the
/// model is refitted there (below it the coefficients move by less than a tenth of their share).
pub const SETTLE_SHIFT_SIGMA: f64 = 0.1;

/// The set-up estimated where the data can ([`settle_setup`]), and the coefficients moved where
/// the slow drifts' priors and the data put them ([`Uncertainty::drift_shift`]); `known`: an
/// uncertainty computed before, reused if it is this one ([`Computed`]).
pub fn settle(
    effects: &[&dyn Effect],
    prep: Prepared,
    cfg: &Config,
    id: Identification,
    known: Option<&Computed>,
) -> anyhow::Result<Settled> {
    let unc = uncertainty_reusing(effects, &prep, cfg, &id, known)?;
    let fitted = known
        .and_then(|k| k.settling_for(effects, &prep, cfg, &id))
        .cloned();
    settle_about(effects, prep, cfg, id, unc, fitted)
}

/// [`settle`] with the uncertainty about the stated set-up, `unc`, computed already (what a
/// misstated set-up is weighed with, [`crate::diagnose::misstated::weigh`], beside the refit);
/// `fitted`: the model refitted where it settles, when that was made before ([`settling_fit`]
/// from the same arguments).
pub fn settle_about(
    effects: &[&dyn Effect],
    prep: Prepared,
    cfg: &Config,
    id: Identification,
    unc: Uncertainty,
    fitted: Option<Identification>,
) -> anyhow::Result<Settled> {
    let (mut settled, moved) = settle_setup(effects, prep, cfg, id, unc, fitted)?;
    if moved {
        // The shift is the slow drifts' reach from the fit it is taken about: about the stated
        // set-up's misfit it would also soak up the set-up's error the refit has repaired.
        settled.unc.drift_shift = slow_drift_shift(effects, &settled.prep, cfg, &settled.id)?;
    }
    if let Some(est) = settled.id.refined.as_mut() {
        for (v, d) in est.value.iter_mut().zip(&settled.unc.drift_shift) {
            *v += d;
        }
    }
    Ok(settled)
}

/// Where [`settle`] refits, as offsets from the stated set-up (latitude deg, clock ppm, gravity
/// ppm): the knobs' posterior ([`Uncertainty::setup_shift`]) when it lies more than
/// [`SETTLE_SHIFT_SIGMA`] of a knob's posterior 1σ from the stated set-up; `None` where the
/// data contradict the stated set-up (the linearised posterior is then no place to refit), for
/// a single pass (no knobs weighed) or when it lies closer.
pub(crate) fn settling_refit(unc: &Uncertainty) -> Option<[f64; 3]> {
    if !unc.untrusted_reasons().is_empty() {
        return None;
    }
    let knobs = unc.contributions.get(1..4)?;
    let far = knobs
        .iter()
        .zip(unc.setup_shift)
        .any(|(c, d)| c.posterior_sigma > 0.0 && d.abs() > SETTLE_SHIFT_SIGMA * c.posterior_sigma);
    far.then_some(unc.setup_shift)
}

/// The model of `effects` refitted from the fit `id` with the set-up moved by `shift` (latitude
/// deg, clock ppm, gravity ppm): what [`settle`] refits at [`settling_refit`].
pub(crate) fn settling_fit(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
    shift: [f64; 3],
) -> anyhow::Result<Identification> {
    let p = moved(prep, shift);
    let model = build_model(p.site, effects, cfg)?;
    super::identify_from(&model, &p, cfg, id)
}

/// A fit as [`refit`] returns one: −2 ln p(y) and the parameters after the angles at the last
/// node. A settling fit ([`settling_fit`]) is the same Gauss–Newton passes from the same nominal
/// as a refit there, so the same numbers.
pub(crate) fn as_refit(fit: &Identification) -> Option<(f64, DVector<f64>)> {
    let last = fit.trajectory.last()?;
    Some((
        neg2_log_evidence(&fit.innovations),
        last.rows(ANGLES, last.len() - ANGLES).into_owned(),
    ))
}

/// The set-up's part of [`settle`], and whether it refitted: with `unc`, [`uncertainty`] about
/// the stated set-up, if the knobs' posterior lies away from it (gravity 50 ppm off a value the
/// data measure to 0.2 ppm), the model refitted there. The estimate is then the posterior's, not
/// the stated set-up's.
fn settle_setup(
    effects: &[&dyn Effect],
    prep: Prepared,
    cfg: &Config,
    id: Identification,
    unc: Uncertainty,
    fitted: Option<Identification>,
) -> anyhow::Result<(Settled, bool)> {
    let Some(shift) = settling_refit(&unc) else {
        return Ok((
            Settled {
                prep,
                id,
                unc,
                at_posterior: None,
            },
            false,
        ));
    };
    let knobs = &unc.contributions[1..4];
    let mut p = moved(&prep, shift);
    for c in knobs {
        if let (Some(o), Some((v, unit))) = (c.offset, c.stated) {
            if o.abs() > 3.0 * c.posterior_sigma {
                p.findings.push(crate::quality::Finding {
                    kind: crate::quality::Kind::SetUp,
                    message: format!(
                        "the {} is estimated from the data with its prior: {} {unit}{} (stated {}, prior 1σ {}); the coefficients are the fit's there",
                        c.source,
                        crate::format::pm(v + o, c.knob_sigma()),
                        if c.sigma_drifts_free.is_some() { " with the slow drifts free" } else { "" },
                        crate::format::sig(v, 9),
                        c.prior
                    ),
                    start_s: None,
                    end_s: None,
                    samples: 0,
                    action: crate::quality::Action::Repaired,
                });
            }
        }
    }
    let refitted = match fitted {
        Some(f) => Ok(f),
        None => settling_fit(effects, &prep, cfg, &id, shift),
    };
    let at_posterior = refitted.as_ref().ok().and_then(as_refit);
    match refitted {
        Ok(id2) if follows_linear(&unc, &id, &id2) => {
            let mut unc = unc;
            // The fit's own covariance at the new point; the set-up's terms as computed.
            let n = id2.best().value.len();
            let old = id.best().cov.clone();
            unc.total_cov = &unc.total_cov - &old + &id2.best().cov;
            unc.total_sigma = (0..n)
                .map(|k| unc.total_cov[(k, k)].max(0.0).sqrt())
                .collect();
            Ok((
                Settled {
                    prep: p,
                    id: id2,
                    unc,
                    at_posterior,
                },
                true,
            ))
        }
        // The refit failed, or is no estimate: the stated set-up's fit stands, with its
        // uncertainty.
        _ => Ok((
            Settled {
                prep,
                id,
                unc,
                at_posterior,
            },
            false,
        )),
    }
}

/// Whether the refit `to` at the set-up's posterior moved the coefficients from `from` as the
/// knobs' linear model predicts (`∂ĉ/∂u · shift`), within one total 1σ each. Where it did not,
/// −2 ln p is no quadratic over the move and the refit is no estimate: on a latitude written
/// "10" (prior 0.29°, a nearly flat profile near the equator) the set-up moved 0.49° and DZx
/// moved 11 of its total 1σ where the model predicted a fraction of one; exit 0.
fn follows_linear(unc: &Uncertainty, from: &Identification, to: &Identification) -> bool {
    let Some(k) = &unc.knobs else {
        return true;
    };
    let shift_u = DVector::from_iterator(
        3,
        (0..3).map(|j| {
            if k.unit[j] > 0.0 {
                unc.setup_shift[j] / k.unit[j]
            } else {
                0.0
            }
        }),
    );
    let predicted = &k.sens * shift_u;
    let (a, b) = (&from.best().value, &to.best().value);
    (0..predicted.len()).all(|i| ((b[i] - a[i]) - predicted[i]).abs() <= unc.total_sigma[i])
}

#[cfg(test)]
mod tests {
    use super::{written_precision, Contribution, SetupCheck, Uncertainty};
    use nalgebra::DMatrix;

    #[test]
    fn a_contradicted_set_up_states_each_knob_with_the_1sigma_the_run_supports() {
        // The drift-trend recording of the speed set: the latitude's posterior 1σ with the slow
        // drifts held at zero was 0.0019°, with them free 0.021°. The digits check printed
        // "40.723 ± 0.021 deg" and, in the same run, the χ² check "40.7231 ± 0.0019 deg".
        let knob = |source, stated: (f64, &'static str), offset, held, free| {
            let mut c = Contribution::new(source, String::new(), DMatrix::zeros(12, 12));
            (c.stated, c.offset) = (Some(stated), Some(offset));
            // Only a latitude has written digits (39.1: ±0.05°).
            c.bound = (source == "latitude").then_some(0.05);
            (c.posterior_sigma, c.sigma_drifts_free) = (held, free);
            c
        };
        let mut unc = Uncertainty::exact(&DMatrix::identity(12, 12));
        unc.contributions = vec![
            Contribution::new("start attitude", String::new(), DMatrix::zeros(12, 12)),
            knob("latitude", (39.1, "deg"), 1.6231, 0.0019, Some(0.021)),
            knob("clock rate", (0.0, "ppm"), 56.0, 20.0, None),
            knob("gravity", (0.0, "ppm"), -146.22, 0.24, None),
        ];
        unc.setup_check = Some(SetupCheck {
            chi2: 3199.5,
            dof: 2,
            p_value: 0.0,
        });
        let reasons = unc.untrusted_reasons();
        assert_eq!(reasons.len(), 2, "{reasons:?}");
        for r in &reasons {
            assert!(r.contains("40.723 ± 0.021 deg"), "{r}");
            assert!(!r.contains("0.0019"), "{r}");
        }
        // A knob without a wider 1σ keeps its posterior's.
        assert!(reasons[1].contains("56 ± 20 ppm"), "{}", reasons[1]);
    }

    #[test]
    fn a_latitude_keeps_its_written_digits_through_radians() {
        // −30.3 and 60.25 come back from radians as −30.299999999999997 and 60.25000000000001:
        // taken at face value they had 15 and 14 decimals (a prior of 1e-4°, the floor) and a
        // run 0.03° off was trusted 47σ off. Exact to rounding (1e-12).
        let r = 12f64.sqrt();
        for (x, decimals) in [(39.1, 1), (-30.3, 1), (60.25, 2), (39.1051, 4), (39.0, 0)] {
            for y in [x, f64::to_degrees(f64::to_radians(x))] {
                let want = 10f64.powi(-decimals) / r;
                assert!(
                    (written_precision(y) / want - 1.0).abs() < 1e-12,
                    "{y}: {} against {want}",
                    written_precision(y)
                );
            }
        }
    }

    /// The shift a settled fit takes from the daily drift alone is the one the full
    /// marginalisation gives, bit for bit (the trend's and temperature's passes, skipped, add
    /// exact zeros), and it is no zero vector (the check could not fail on one). 30 h at 10 s.
    /// `settle`'s refit at the set-up's posterior is the misstatements' refit of the stated
    /// set-up with its priors: the same place, bit for bit, and the same fit, so `assess` makes
    /// it once (crate::assess). Gravity stated 40 ppm off (prior 30 ppm; the run measures it to
    /// a fraction of a ppm): the posterior lies far from the stated set-up, and settle refits.
    /// Bit-equal, not within a tolerance: the two are the same passes from the same nominal.
    #[test]
    fn the_settling_refit_is_the_misstatements_refit_with_the_priors() {
        use crate::diagnose::misstated;
        use crate::identify::{build_model, identify, Config};
        let mut sc = crate::simulate::Scenario::paper();
        sc.hours = 30.0;
        sc.rate_s = 10.0;
        sc.setup_errors.gravity_ppm = 40.0;
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let effects = [crate::catalog::paper()];
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let unc = super::uncertainty(&effects, &prep, &cfg, &id).unwrap();
        let at = super::settling_refit(&unc).expect("the posterior lies far: settle refits");
        assert_eq!(Some(at), misstated::priors_refit_at(&unc));
        let settled =
            super::settle_about(&effects, prep.clone(), &cfg, id.clone(), unc.clone(), None);
        let (f, c) = settled.unwrap().at_posterior.expect("settle's refit");
        let (f_own, c_own) = super::refit(&super::moved(&prep, at), &effects, &cfg, &id).unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(f.to_bits(), f_own.to_bits());
        assert_eq!(bits(c.as_slice()), bits(c_own.as_slice()));
        // The misstatements weighed on it are those weighed on their own refit.
        let own = misstated::weigh(&effects, &prep, &cfg, (&id, &unc), None).unwrap();
        let shared = misstated::refits(&effects, &prep, &cfg, &id, &unc, true)
            .unwrap()
            .expect("knobs weighed")
            .weigh(&effects, &prep, &cfg, (&id, &unc), Some((f, c)))
            .unwrap();
        assert!(!own.alternatives.is_empty());
        assert_eq!(own.alternatives.len(), shared.alternatives.len());
        for (a, b) in own.alternatives.iter().zip(&shared.alternatives) {
            assert_eq!(
                a.evidence_gain.to_bits(),
                b.evidence_gain.to_bits(),
                "{}",
                a.effect
            );
            assert_eq!(bits(&a.shift), bits(&b.shift), "{}", a.effect);
        }
        assert_eq!(bits(&own.about), bits(&shared.about));
        // Kept for a later assessment of the same fit (diagnose's starting fit): the same
        // misstatements, and settle there takes the kept refit — the same fit as its own.
        let mut kept = super::Computed::new(&effects, &prep, &cfg, &id, unc.clone());
        let weighed = misstated::weigh(&effects, &prep, &cfg, (&id, &unc), Some(&mut kept));
        let weighed = weighed.unwrap();
        for (a, b) in own.alternatives.iter().zip(&weighed.alternatives) {
            assert_eq!(
                a.evidence_gain.to_bits(),
                b.evidence_gain.to_bits(),
                "{}",
                a.effect
            );
        }
        assert!(kept.settling_for(&effects, &prep, &cfg, &id).is_some());
        let with = super::settle(&effects, prep.clone(), &cfg, id.clone(), Some(&kept)).unwrap();
        let without = super::settle(&effects, prep.clone(), &cfg, id.clone(), None).unwrap();
        let value = |s: &super::Settled| bits(&s.id.best().value);
        assert_eq!(value(&with), value(&without));
        assert_ne!(value(&without), bits(&id.best().value), "settle refitted");
    }

    #[test]
    fn the_slow_drifts_shift_alone_is_the_full_marginalisations() {
        use crate::identify::{build_model, identify, Config};
        let mut sc = crate::simulate::Scenario::paper();
        sc.hours = 30.0;
        sc.rate_s = 10.0;
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let effects = [crate::catalog::paper()];
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let full = super::slow_drifts(&effects, &prep, &cfg, &id).unwrap();
        assert!(
            full.contributions.len() >= 2,
            "only {} slow drift(s) apply: nothing is skipped",
            full.contributions.len()
        );
        let alone = super::slow_drift_shift(&effects, &prep, &cfg, &id).unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&alone), bits(&full.shift));
        assert!(alone.iter().any(|x| *x != 0.0), "no shift: {alone:?}");
    }
}
