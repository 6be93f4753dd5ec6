//! One definition of "the model explains the measurements", used by `identify` (exit status),
//! `diagnose` (verdict, when the ladder stops) and the report.
//!
//! A converged model is **consistent** when all three hold (thresholds named once, in
//! [`Thresholds`]):
//! - the mean NIS/3 lies in its two-sided band for 3N degrees of freedom,
//!   `[χ²_{(1−P)/2}(3N), χ²_{(1+P)/2}(3N)]/3N` with `P = nis_band_prob`;
//! - the whitened innovations are white: Ljung–Box `p ≥ whiteness_alpha`
//!   ([`whiteness`]);
//! - the residual along the converged trajectory is at the noise floor: `RMS/floor <
//!   max(max_rms_over_floor, 1 + z·floor_rel_sd)` on every axis, z = 3.29 (the band's
//!   two-sided 99.9 % point): a floor estimated from few samples (e.g. 36 h at 30 s: 2.7 %) is
//!   itself uncertain by more than the 5 % the fixed limit allows.
//!
//! The levels are chosen so that a clean run fails by chance about 0.2 % of the time (two tests at
//! 1e-3, the RMS check being implied by the NIS one on clean data), while a missing effect that
//! raises the residual by 5 % is caught.

use serde::Serialize;

use crate::stats::{chi2_quantile, chi2_sf};

/// The thresholds of consistency.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub(crate) struct Thresholds {
    /// Probability content of the two-sided NIS band.
    pub nis_band_prob: f64,
    /// Smallest Ljung–Box p-value accepted as white.
    pub whiteness_alpha: f64,
    /// Largest residual RMS / noise floor on any axis.
    pub max_rms_over_floor: f64,
    /// Smallest χ² p-value accepted for one run's coefficients against a joint estimate
    /// ([`agreement`]).
    pub agreement_alpha: f64,
}

impl Default for Thresholds {
    fn default() -> Self {
        Thresholds {
            nis_band_prob: 0.999,
            whiteness_alpha: 1e-3,
            max_rms_over_floor: 1.05,
            agreement_alpha: 1e-3,
        }
    }
}

/// The consistency of one converged model with the measurements.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Consistency {
    /// Mean NIS/3 (1 when consistent).
    pub nis_mean: f64,
    /// Its band at [`Thresholds::nis_band_prob`].
    pub nis_band: [f64; 2],
    /// Ljung–Box p-value of the whitened innovations.
    pub whiteness_p: f64,
    /// Residual RMS over the noise floor, per axis.
    pub rms_over_floor: [f64; 3],
    /// What fails, in words (empty: consistent).
    pub failures: Vec<String>,
}

impl Consistency {
    /// Whether every check passes.
    pub fn is_consistent(&self) -> bool {
        self.failures.is_empty()
    }
}

/// The NIS/3 band for `updates` three-axis updates at probability `prob`.
pub(crate) fn nis_band(updates: usize, prob: f64) -> [f64; 2] {
    let dof = 3.0 * updates.max(1) as f64;
    [
        chi2_quantile(0.5 * (1.0 - prob), dof) / dof,
        chi2_quantile(0.5 * (1.0 + prob), dof) / dof,
    ]
}

/// The NIS/3 band widened for the noise floor's own uncertainty: the floor is estimated from the
/// data with relative 1σ `floor_rel_sd`, which scales every NIS by (σ/σ̂)² — a relative 1σ of
/// 2·`floor_rel_sd` — independently of the χ² scatter; the two half-widths add in quadrature.
/// On a long record at a short period the χ² band alone (±0.6 % at 216 000 updates) is narrower
/// than the floor can be known (±0.8 % at 1σ from 216 000 raw samples).
pub(crate) fn nis_band_with_floor(updates: usize, prob: f64, floor_rel_sd: f64) -> [f64; 2] {
    let [lo, hi] = nis_band(updates, prob);
    let z = crate::stats::normal_quantile(0.5 * (1.0 + prob));
    let extra = z * 2.0 * floor_rel_sd.max(0.0);
    [
        1.0 - ((1.0 - lo).powi(2) + extra * extra).sqrt(),
        1.0 + ((hi - 1.0).powi(2) + extra * extra).sqrt(),
    ]
}

/// The RMS/floor limit: [`Thresholds::max_rms_over_floor`], widened to `1 + z·sd` when the ratio
/// itself is that uncertain on a consistent run (z from the NIS band's probability). Two spreads
/// add: the floor estimate's (`floor_rel_sd`) and the residual RMS's own over `updates`
/// residuals, `1/√(2N)` (N·RMS²/σ² ~ χ²(N)). Without the second, a clean 24-h run (N = 1 441,
/// 1.9 %) fails the 1.05 limit on one axis in a few percent of runs.
pub(crate) fn rms_limit(t: &Thresholds, floor_rel_sd: f64, updates: usize) -> f64 {
    let z = crate::stats::normal_quantile(0.5 + 0.5 * t.nis_band_prob);
    let rms_rel_sd = 1.0 / (2.0 * updates.max(1) as f64).sqrt();
    let sd = floor_rel_sd.hypot(rms_rel_sd);
    t.max_rms_over_floor.max(1.0 + z * sd)
}

/// Assesses the statistics of one converged model; `floor_rel_sd` is the relative 1σ of the
/// noise floor estimate (0 when the floor is given).
pub(crate) fn assess(
    nis_mean: f64,
    updates: usize,
    whiteness_p: f64,
    rms_over_floor: [f64; 3],
    floor_rel_sd: f64,
    t: &Thresholds,
) -> Consistency {
    let band = nis_band_with_floor(updates, t.nis_band_prob, floor_rel_sd);
    let mut failures = vec![];
    if !(band[0]..=band[1]).contains(&nis_mean) {
        failures.push(format!(
            "mean NIS/3 = {} lies outside its {:.1} % band {:.3}–{:.3}",
            crate::format::sci(nis_mean),
            100.0 * t.nis_band_prob,
            band[0],
            band[1]
        ));
    }
    if whiteness_p.is_nan() || whiteness_p < t.whiteness_alpha {
        failures.push(format!(
            "the innovations are not white (Ljung–Box p = {whiteness_p:.1e} < {:.0e})",
            t.whiteness_alpha
        ));
    }
    let limit = rms_limit(t, floor_rel_sd, updates);
    if rms_over_floor.iter().any(|r| r.is_nan() || *r >= limit) {
        failures.push(format!(
            "the residual RMS is [{:.3}, {:.3}, {:.3}] × the noise floor (limit {limit:.3})",
            rms_over_floor[0], rms_over_floor[1], rms_over_floor[2]
        ));
    }
    Consistency {
        nis_mean,
        nis_band: band,
        whiteness_p,
        rms_over_floor,
        failures,
    }
}

/// Autocorrelation and Ljung–Box test of the whitened innovations.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Whiteness {
    /// Autocorrelation at lags 1..=m, per axis.
    pub acf: Vec<[f64; 3]>,
    /// 95 % bound for a white sequence, ±1.96/√N.
    pub acf_bound95: f64,
    /// Ljung–Box statistic summed over the three axes.
    pub ljung_box_q: f64,
    /// Its degrees of freedom.
    pub dof: f64,
    /// p-value (small: not white).
    pub p_value: f64,
}

/// Lags of the Ljung–Box test ([`crate::diagnose::DiagnoseConfig::lags`]'s default).
pub const LJUNG_BOX_LAGS: usize = 20;

/// Autocorrelation of each axis' whitened innovations and the Ljung–Box test over the three axes.
///
/// The whitened innovations of a filter are white under its model by construction (they are not
/// residuals of a fit), so the Ljung–Box statistic is referred to χ²(3m) without the reduction
/// for fitted ARMA parameters; the 12+ fitted constants shift the innovations by O(1/N).
pub fn whiteness(w: &[[f64; 3]], lags: usize) -> Whiteness {
    let n = w.len();
    let lags = lags.min(n.saturating_sub(2)).max(1);
    let mut acf = vec![[0.0; 3]; lags];
    let mut q = 0.0;
    for a in 0..3 {
        let mean = w.iter().map(|x| x[a]).sum::<f64>() / n as f64;
        let var = w.iter().map(|x| (x[a] - mean).powi(2)).sum::<f64>();
        for k in 1..=lags {
            let c: f64 = (k..n)
                .map(|j| (w[j][a] - mean) * (w[j - k][a] - mean))
                .sum();
            let r = c / var.max(1e-300);
            acf[k - 1][a] = r;
            q += r * r / (n - k) as f64;
        }
    }
    let q = n as f64 * (n as f64 + 2.0) * q;
    let dof = 3.0 * lags as f64;
    Whiteness {
        acf,
        acf_bound95: 1.96 / (n as f64).sqrt(),
        ljung_box_q: q,
        dof,
        p_value: chi2_sf(q, dof),
    }
}

/// Whether one run's coefficients agree with a joint estimate of several runs.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Agreement {
    /// `dᵀ D⁺ d`: d the run's own estimate minus the joint one, D the covariance of d.
    pub chi2: f64,
    /// Degrees of freedom: the directions in which D is not negligible.
    pub dof: usize,
    /// The χ²(dof) tail probability of `chi2`.
    pub p_value: f64,
}

impl Agreement {
    /// Why the run disagrees with the joint estimate (`None`: it agrees at
    /// [`Thresholds::agreement_alpha`]).
    pub fn failure(&self) -> Option<String> {
        let alpha = Thresholds::default().agreement_alpha;
        (self.p_value.is_nan() || self.p_value < alpha).then(|| {
            format!(
                "its coefficients disagree with the other runs' beyond their total 1σ (χ² = {:.1} for {} degrees of freedom, p = {:.1e} < {alpha:.0e})",
                self.chi2, self.dof, self.p_value
            )
        })
    }
}

/// One run's estimate `own` (covariance `own_cov`, its set-up's share included) against the
/// joint estimate `joint` (covariance `joint_cov`) it is part of. For the joint estimate as the
/// information-weighted mean of the runs', the difference `d = own − joint` has covariance
/// `D = own_cov − joint_cov` (an estimate minus an efficient one it feeds: their covariance is
/// the efficient one's). `χ² = dᵀ D⁺ d` over the eigen-directions of D above 1e-9 of its largest
/// (a direction only this run informs has d ≈ 0 and D ≈ 0: no test there).
pub fn agreement(
    own: &[f64],
    own_cov: &nalgebra::DMatrix<f64>,
    joint: &[f64],
    joint_cov: &nalgebra::DMatrix<f64>,
) -> Agreement {
    let d = nalgebra::DVector::from_iterator(own.len(), own.iter().zip(joint).map(|(a, b)| a - b));
    let cov = own_cov - joint_cov;
    let eig = ((&cov + cov.transpose()) * 0.5).symmetric_eigen();
    let top = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
    let mut chi2 = 0.0;
    let mut dof = 0;
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l > 1e-9 * top && l > 0.0 {
            chi2 += eig.eigenvectors.column(k).dot(&d).powi(2) / l;
            dof += 1;
        }
    }
    let p_value = if dof == 0 {
        1.0
    } else {
        crate::stats::chi2_sf(chi2, dof as f64)
    };
    Agreement { chi2, dof, p_value }
}

/// One run of a joint fit against the joint estimate `joint` ([`agreement`]: the run's own
/// estimate with its set-up's share, [`crate::identify::joint::RunFit`]).
pub fn run_agreement(
    fit: &crate::identify::joint::RunFit,
    joint: &crate::identify::Estimate,
) -> Agreement {
    agreement(
        &fit.own.value,
        &(&fit.own.cov + &fit.setup.cov),
        &joint.value,
        &joint.cov,
    )
}

/// The consistency of the converged identification (`None` for a single pass).
pub fn consistency_of(
    id: &crate::identify::Identification,
    prep: &crate::identify::Prepared,
) -> Option<Consistency> {
    id.refined.as_ref()?;
    Some(fit_consistency(
        &id.innovations,
        id.residual_rms_mps2(prep),
        prep,
    ))
}

/// The consistency ([`crate::consistency`]) of a fit's innovations and residual RMS against the
/// run's noise floor.
pub fn fit_consistency(
    innovations: &[estimator_core::Residual],
    rms_mps2: [f64; 3],
    prep: &crate::identify::Prepared,
) -> Consistency {
    let whitened: Vec<[f64; 3]> = innovations.iter().map(|r| r.whitened).collect();
    let white = whiteness(&whitened, LJUNG_BOX_LAGS);
    let floor = prep.floor_mps2();
    assess(
        crate::identify::mean_nis(innovations),
        innovations.len(),
        white.p_value,
        [0, 1, 2].map(|i| rms_mps2[i] / floor[i]),
        prep.floor_rel_sd(),
        &Thresholds::default(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn band_matches_chi2_reference() {
        // χ²(10800) quantiles at 0.0005 and 0.9995 over 10800 (scipy.stats.chi2.ppf):
        // 0.955827 and 1.045386. statrs inverts the regularised gamma exactly; 1e-4 is a tenth
        // of the band's sampling width, so a wrong formula (e.g. a normal approximation without
        // skew, off by 4e-4) fails.
        let b = nis_band(3600, 0.999);
        assert!((b[0] - 0.955827).abs() < 1e-4, "{b:?}");
        assert!((b[1] - 1.045386).abs() < 1e-4, "{b:?}");
    }

    #[test]
    fn the_band_widens_by_the_floors_uncertainty() {
        // No floor uncertainty: the χ² band. 1 % floor uncertainty on 216 000 updates: the NIS
        // scale is uncertain by 2 %, so 3.29 × 2 % ≈ 6.6 % dominates the χ² ±0.6 %.
        assert_eq!(nis_band_with_floor(3600, 0.999, 0.0), nis_band(3600, 0.999));
        let b = nis_band_with_floor(216_000, 0.999, 0.01);
        assert!((b[1] - 1.0659).abs() < 2e-3, "{b:?}");
        assert!((1.0 - b[0] - 0.0659).abs() < 2e-3, "{b:?}");
    }

    #[test]
    fn the_rms_limit_widens_only_for_a_poorly_known_floor() {
        // z = 3.29 at 99.9 %: 216 000 samples (rel. sd 0.38 %) on 3 600 updates (RMS rel. sd
        // 1/√7200 = 1.18 %; together 1.24 %, 1.041) keep 1.05; a floor from 4 321 samples
        // (2.66 %) on 3 600 updates gives 1 + 3.29 × hypot(2.66, 1.18) % = 1.0958.
        let t = Thresholds::default();
        assert_eq!(rms_limit(&t, 1.75 / 216_000f64.sqrt(), 3600), 1.05);
        let wide = rms_limit(&t, 1.75 / 4321f64.sqrt(), 3600);
        assert!((wide - 1.0958).abs() < 1e-3, "{wide}");
    }

    #[test]
    fn the_rms_limit_counts_the_residuals_own_spread() {
        // A clean 24-h run at 60 s: 1 441 updates, RMS rel. sd 1/√2882 = 1.86 %, so the limit is
        // 1 + 3.29 × 1.86 % = 1.0613; a seeded clean run (seed 7) had 1.053 on one axis and was
        // refused before. 100 updates: 1 + 3.29/√200 = 1.233.
        let t = Thresholds::default();
        let day = rms_limit(&t, 0.0, 1441);
        assert!((day - 1.0613).abs() < 1e-3, "{day}");
        assert!(day > 1.053);
        let short = rms_limit(&t, 0.0, 100);
        assert!((short - 1.2327).abs() < 1e-3, "{short}");
    }

    #[test]
    fn each_failure_is_named() {
        let t = Thresholds::default();
        let ok = assess(1.0, 3600, 0.5, [1.0, 1.0, 1.0], 0.0, &t);
        assert!(ok.is_consistent());
        let bad = assess(0.94, 3600, 1e-5, [1.0, 1.2, 1.0], 0.0, &t);
        assert_eq!(bad.failures.len(), 3, "{:?}", bad.failures);
    }

    #[test]
    fn agreement_tests_only_the_directions_the_difference_can_take() {
        // d = (1, 0.5): D = own − joint = diag(1, 0); the second direction, which only this
        // run informs (D = 0), is not tested; χ² = 1²/1 on 1 dof, tail 0.3173 (scipy
        // chi2.sf(1, 1) = 0.31731); statrs's regularised gamma agrees to 1e-10.
        let own_cov =
            nalgebra::DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![2.0, 1.0]));
        let joint_cov = nalgebra::DMatrix::identity(2, 2);
        let a = agreement(&[1.0, 0.5], &own_cov, &[0.0, 0.0], &joint_cov);
        assert_eq!(a.dof, 1);
        assert!((a.chi2 - 1.0).abs() < 1e-12, "{a:?}");
        assert!((a.p_value - 0.317_310_507_9).abs() < 1e-8, "{a:?}");
        assert!(a.failure().is_none());
        // Five of D's 1σ apart: χ² 25, p 5.7e-7 < 1e-3, named.
        let far = agreement(&[5.0, 0.0], &own_cov, &[0.0, 0.0], &joint_cov);
        assert!(
            far.failure().is_some_and(|m| m.contains("disagree")),
            "{far:?}"
        );
    }
}
