//! Slow gyro drifts a laboratory puts on a run — a drift that follows the solar day (its thermal
//! cycle) and a drift that changes steadily over the run (its slower temperature changes, the
//! gyros' run-in) — as set-up uncertainties: the model with the drift appended at a physical
//! prior is linearised about the fit; what it adds is that covariance less the fit's (shrunk
//! where the data see the drift, the full consider term where they do not), and where it puts the
//! parameters is the shift [`super::setup::settle`] applies (the daily drift's only:
//! [`SlowDrift::shifts_the_estimate`]). The size is the prior's, or a larger
//! one where the data's evidence asks for it ([`size`]), up to past the catalog effect's own
//! prior: a catalog twin the data cannot rule out is then carried in the total 1σ, not a reason
//! to distrust it (`assess::carried_as_setup`). Nothing when the model already holds the effect.

use anyhow::Context as _;
use estimator_core::effects::{DriftDaily, DriftTrend, Effect, TempDrift};
use estimator_core::model::ANGLES;
use nalgebra::{DMatrix, DVector};

use super::setup::{Contribution, SetupPriors};
use super::smoother::linearised_pass;
use super::{build_model, start_prior, Config, Identification, Prepared};

/// One of the slow drifts marginalised.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum SlowDrift {
    /// Six components at the solar day ([`DriftDaily`]).
    Daily,
    /// A trend per axis ([`DriftTrend`]).
    Trend,
    /// A drift proportional to the recorded temperature per axis ([`TempDrift`]; only where the
    /// temperature varies).
    Temperature,
}

impl SlowDrift {
    /// Both, in the order the set-up table lists them.
    pub(crate) const ALL: [SlowDrift; 3] =
        [SlowDrift::Daily, SlowDrift::Trend, SlowDrift::Temperature];

    /// The set-up table's name of the source.
    pub(crate) fn source(self) -> &'static str {
        match self {
            SlowDrift::Daily => "daily drift",
            SlowDrift::Trend => "drift trend",
            SlowDrift::Temperature => "thermal drift",
        }
    }

    /// Whether [`super::setup::settle`] moves the estimate where this drift's prior and the data
    /// put it (the daily drift), or the drift only widens the 1σ (the trend: see
    /// `setup::slow_drifts`).
    pub(crate) fn shifts_the_estimate(self) -> bool {
        self == SlowDrift::Daily
    }

    /// Whether it can act on this recording: a temperature drift only where the recorded
    /// temperature varies (elsewhere it has no row in the set-up table).
    pub(crate) fn applies(self, prep: &Prepared) -> bool {
        self != SlowDrift::Temperature || crate::diagnose::temp_varies(&prep.measurements)
    }

    /// The catalog effect of the same physics.
    pub(crate) fn catalog_name(self) -> &'static str {
        match self {
            SlowDrift::Daily => "drift-daily",
            SlowDrift::Trend => "drift-trend",
            SlowDrift::Temperature => "temp-drift",
        }
    }

    /// The prior 1σ in the effect's units (deg/h; deg/h per h).
    fn prior(self, p: &SetupPriors) -> f64 {
        match self {
            SlowDrift::Daily => p.daily_drift_deg_h,
            SlowDrift::Trend => p.drift_trend_deg_h_per_day / 24.0,
            SlowDrift::Temperature => p.temp_drift_deg_h_per_c,
        }
    }

    /// The prior in the set-up table's words.
    fn label(self, sigma: f64) -> String {
        match self {
            SlowDrift::Daily => format!("{} deg/h per component", crate::format::sig(sigma, 2)),
            SlowDrift::Trend => format!(
                "{} deg/h a day per axis",
                crate::format::sig(sigma * 24.0, 2)
            ),
            SlowDrift::Temperature => {
                format!("{} deg/h per degC per axis", crate::format::sig(sigma, 2))
            }
        }
    }

    /// The effect at prior 1σ `sigma`.
    fn effect(self, sigma: f64) -> Box<dyn Effect> {
        match self {
            SlowDrift::Daily => Box::new(DriftDaily { sigma_degph: sigma }),
            SlowDrift::Trend => Box::new(DriftTrend {
                sigma_deg_h_per_h: sigma,
            }),
            SlowDrift::Temperature => Box::new(TempDrift {
                sigma_deg_h_per_c: sigma,
            }),
        }
    }
}

/// `effects` with `drift` appended.
fn with_drift<'a>(effects: &[&'a dyn Effect], drift: &'a dyn Effect) -> Vec<&'a dyn Effect> {
    let mut with = effects.to_vec();
    with.push(drift);
    with
}

/// One slow drift marginalised about a fit.
pub(crate) struct Marginalised {
    /// What it adds to the parameters' covariance.
    pub contribution: Contribution,
    /// Where it moves them (state order after the angles).
    pub shift: Vec<f64>,
    /// The size it was carried at, its prior 1σ or the data's ([`size`]); `None`: not carried.
    pub size: Option<f64>,
}

/// `kind` marginalised about the fit `id` of `effects` on `prep`.
pub(crate) fn marginalised(
    kind: SlowDrift,
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
) -> anyhow::Result<Marginalised> {
    let sigma0 = kind.prior(&cfg.setup);
    let n = id.best().value.len();
    let none = |label: String| Marginalised {
        contribution: Contribution::new(kind.source(), label, DMatrix::zeros(n, n)),
        shift: vec![0.0; n],
        size: None,
    };
    if sigma0.is_nan() || sigma0 <= 0.0 || effects.iter().any(|e| e.name() == kind.catalog_name()) {
        return Ok(none(kind.label(sigma0)));
    }
    let probe = kind.effect(sigma0);
    if let Err(e) = build_model(prep.site, &with_drift(effects, probe.as_ref()), cfg) {
        // Said in the set-up table, not hidden: the 1σ then lacks this term.
        return Ok(none(format!("not carried: {e}")));
    }
    let added = probe.params().len();
    let nominal = widened(&id.trajectory, added);
    let pass = |sigma: f64| -> anyhow::Result<_> {
        let drift = kind.effect(sigma);
        let with = with_drift(effects, drift.as_ref());
        filter_pass(prep, &with, &nominal, cfg)
    };
    let mut with = pass(sigma0)?;
    let sigma = size(&with, ANGLES + n, sigma0);
    if sigma > sigma0 {
        with = pass(sigma)?;
    }
    // The parameters where the drift's prior and the data put them: one Gauss–Newton step of the
    // augmented model from the converged fit (exact to first order: the drift is linear in its
    // components; the fit itself moves by less than its convergence tolerance, 0.01σ, in such a
    // step), against the fit.
    let fit = id.best();
    let b = with.states.last().context("no states")?;
    let shift: Vec<f64> = (0..n).map(|k| b[ANGLES + k] - fit.value[k]).collect();
    let cov_with = with.final_cov;
    let cov = cov_with.view((ANGLES, ANGLES), (n, n)) - &fit.cov;
    let label = if sigma > sigma0 {
        format!("{}; the data's {}", kind.label(sigma0), kind.label(sigma))
    } else {
        kind.label(sigma0)
    };
    let mut c = Contribution::new(kind.source(), label, cov);
    c.sized_by_data = sigma > sigma0;
    let post = (0..added)
        .map(|k| cov_with[(ANGLES + n + k, ANGLES + n + k)].sqrt())
        .fold(0.0, f64::max);
    c.posterior_sigma = post;
    c.data_sigma =
        (post < 0.99 * sigma).then(|| 1.0 / (1.0 / (post * post) - 1.0 / (sigma * sigma)).sqrt());
    Ok(Marginalised {
        contribution: c,
        shift,
        size: Some(sigma),
    })
}

/// One linearised filter pass (no smoothing: the parameters are constant, the last state is
/// their posterior) of the model of `effects` on `p` about `nominal`, from the start's prior.
fn filter_pass(
    p: &Prepared,
    effects: &[&dyn Effect],
    nominal: &[DVector<f64>],
    cfg: &Config,
) -> anyhow::Result<super::smoother::Smoothed> {
    let m = build_model(p.site, effects, cfg)?;
    let (x0, p0) = start_prior(&m, p, &p.start_sigma());
    Ok(linearised_pass(
        &m,
        &p.measurements,
        nominal,
        &x0,
        &p0,
        false,
    )?)
}

/// The trajectory `nominal` with `added` states (at 0) appended to each node.
fn widened(nominal: &[DVector<f64>], added: usize) -> Vec<DVector<f64>> {
    nominal
        .iter()
        .map(|x| x.clone().resize_vertically(x.len() + added, 0.0))
        .collect()
}

/// The drift's size: its prior 1σ `sigma0`, or a larger one where the data's evidence for it is
/// higher (the size is not known in advance; the physical prior is where it starts, not a cap —
/// as `drift-markov`'s σ, the marginal likelihood decides).
///
/// From the pass at `sigma0` (the components are the states from `first` on): the components'
/// information from the data alone `J = P⁻¹ − σ0⁻²` and their score `h = P⁻¹ m` (P, m their
/// posterior); for a prior σ the evidence is `G(σ) = σ² hᵀ(1 + σ²J)⁻¹h − ln det(1 + σ²J)`,
/// maximised over σ0·1.5^k, k = 0…[`SIZES`], a larger size kept only when it beats σ0 by 2 ln N.
fn size(pass: &super::smoother::Smoothed, first: usize, sigma0: f64) -> f64 {
    let (Some(last), q) = (pass.states.last(), pass.final_cov.nrows() - first) else {
        return sigma0;
    };
    let p = pass.final_cov.view((first, first), (q, q)).into_owned();
    let Some(p_inv) = p.clone().try_inverse() else {
        return sigma0;
    };
    let m = last.rows(first, q).into_owned();
    let h = &p_inv * m;
    let j = p_inv - DMatrix::identity(q, q) / (sigma0 * sigma0);
    let evidence = |sigma: f64| -> f64 {
        let a = DMatrix::identity(q, q) + &j * (sigma * sigma);
        match a.clone().lu().solve(&h) {
            Some(x) => sigma * sigma * h.dot(&x) - a.determinant().max(1e-300).ln(),
            None => f64::NEG_INFINITY,
        }
    };
    let (best, gain) = (0..=SIZES)
        .map(|k| sigma0 * 1.5f64.powi(k as i32))
        .map(|s| (s, evidence(s)))
        .fold(
            (sigma0, f64::NEG_INFINITY),
            |b, x| if x.1 > b.1 { x } else { b },
        );
    // Charged 2 ln N for the N sizes tried above the prior, as every profiled explanation is
    // ([`crate::diagnose::select`]): the best of N noise draws beats the prior by chance.
    if gain - evidence(sigma0) > 2.0 * (SIZES as f64).ln() {
        best
    } else {
        sigma0
    }
}

/// Sizes tried above the prior: σ0·1.5^k, k = 1…10 (up to 58× the prior: past the catalog
/// effects' priors, 0.01 deg/h and 0.01 deg/h a day, from the defaults 3e-4).
const SIZES: usize = 10;

/// The knobs (latitude, clock rate, gravity) with the carried slow drifts free: a drift trend
/// and a latitude bend the platform's turn alike, so a trend the data cannot rule out widens what
/// the data say of the latitude, and the latitude carries the trend into the coefficients (a
/// trend at half its detection limit moved DXx by 1.6σ through the latitude while each term,
/// taken with the other held, showed 0.03σ).
///
/// For a model linear in coefficients c, knobs u and drifts d (prior `N(0, Σ)`), with `J =
/// ∂d̂/∂u` at fixed set-up and `P_dd`, `P_cd` the drifts' posterior blocks:
///
/// ```text
/// H_with = H − 2 Jᵀ P_dd⁻¹ J            (−2 ln p(y|u) with the drifts integrated out)
/// S_with = S + P_cd P_dd⁻¹ J            (∂ĉ/∂u with the drifts estimated along)
/// ```
///
/// `J` (the drifts' estimate moved per prior 1σ of each knob) and `P` come from one replay of
/// the model with the drifts carrying the knobs' signature ([`drift_replay`]). `km` is the
/// knobs' model without the drifts; returns its Hessian and sensitivity with them, or `None`
/// when no drift is carried. (The set-up's uncertainty runs the replay beside the knobs' own
/// and applies [`DriftReplay::knobs_with_drifts`]; this is both in one, for the tests.)
#[cfg(test)]
pub(crate) fn knobs_with_drifts(
    carried: &[(SlowDrift, f64)],
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
    km: &super::setup::KnobModel,
) -> anyhow::Result<Option<(DMatrix<f64>, DMatrix<f64>)>> {
    let mask = [0, 1, 2].map(|k| km.unit[k] > 0.0);
    let replay = drift_replay(carried, effects, prep, cfg, id, mask)?;
    Ok(replay.and_then(|r| r.knobs_with_drifts(km)))
}

/// The replay [`knobs_with_drifts`] reads `J` and `P` from: the model with the `carried` drifts,
/// the knobs of `mask` (latitude, clock rate, gravity) carrying their signature. It needs no
/// knob model, so it can run beside the replay that makes one. `None` when no drift is carried
/// or no knob is live.
pub(crate) fn drift_replay(
    carried: &[(SlowDrift, f64)],
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
    mask: [bool; 3],
) -> anyhow::Result<Option<DriftReplay>> {
    if carried.is_empty() || !mask.contains(&true) {
        return Ok(None);
    }
    let drifts: Vec<Box<dyn Effect>> = carried.iter().map(|&(k, s)| k.effect(s)).collect();
    let mut with = effects.to_vec();
    with.extend(drifts.iter().map(|d| d.as_ref()));
    let n = id.best().value.len();
    let q: usize = drifts.iter().map(|d| d.params().len()).sum();
    let nominal = widened(&id.trajectory, q);
    let (pass, sig) =
        super::knob_signature::knob_signature(prep, &with, cfg, &nominal, (mask, &[]))?;
    let first = ANGLES + n;
    Ok(Some(DriftReplay {
        p_dd: pass.final_cov.view((first, first), (q, q)).into_owned(),
        p_cd: pass.final_cov.view((ANGLES, first), (n, q)).into_owned(),
        psi_drifts: sig.psi_final.rows(first, q).into_owned(),
        mask,
    }))
}

/// What [`drift_replay`] keeps: the drifts' posterior blocks and their rows of the knobs'
/// signature (per unit of each knob).
pub(crate) struct DriftReplay {
    p_dd: DMatrix<f64>,
    p_cd: DMatrix<f64>,
    psi_drifts: DMatrix<f64>,
    mask: [bool; 3],
}

impl DriftReplay {
    /// The knobs' Hessian and sensitivity with the drifts free (the formulas of
    /// [`knobs_with_drifts`]), from the knobs' model `km` without them; `None` where `P_dd` is singular or a result not finite.
    pub(crate) fn knobs_with_drifts(
        &self,
        km: &super::setup::KnobModel,
    ) -> Option<(DMatrix<f64>, DMatrix<f64>)> {
        let p_dd_inv = self.p_dd.clone().try_inverse()?;
        let mut j = DMatrix::zeros(self.p_dd.nrows(), 3);
        for k in (0..3).filter(|&k| self.mask[k] && km.unit[k] > 0.0) {
            j.set_column(k, &(self.psi_drifts.column(k) * km.unit[k]));
        }
        let hess = &km.hess - (j.transpose() * &p_dd_inv * &j) * 2.0;
        let sens = &km.sens + &self.p_cd * &p_dd_inv * &j;
        if hess.iter().chain(sens.iter()).any(|v| !v.is_finite()) {
            return None;
        }
        // Clamped positive semi-definite, as the knobs' own Hessian is.
        let hess = super::setup::psd_part(&nalgebra::SymmetricEigen::new(hess));
        Some((hess, sens))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::setup::{moved, uncertainty};
    use crate::identify::{identify, neg2_log_evidence};

    /// The knobs' Hessian with the trend integrated out, `H − 2 Jᵀ P_dd⁻¹ J`, against the second
    /// difference of −2 ln p(y) of the model with the trend itself (linearised passes at the
    /// latitude moved by ± a step; 60 h at 10 s). Tolerance 2 %: both linearise about the stated
    /// fit's trajectory at steps of twice the data's 1σ, where −2 ln p is quadratic to well
    /// under that (measured: 501.8 against 501.8); the correction takes 42 % of the latitude's
    /// curvature here (870 without the trend), so a wrong sign or factor fails.
    #[test]
    fn the_latitudes_curvature_with_the_trend_free_is_the_augmented_models() {
        let mut sc = crate::simulate::Scenario::paper();
        sc.hours = 60.0;
        sc.rate_s = 10.0;
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let effects = [crate::catalog::paper()];
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let unc = uncertainty(&effects, &prep, &cfg, &id).unwrap();
        let km = unc.knobs.as_ref().unwrap();
        let sigma = SlowDrift::Trend.prior(&cfg.setup);
        let (hess, _) =
            knobs_with_drifts(&[(SlowDrift::Trend, sigma)], &effects, &prep, &cfg, &id, km)
                .unwrap()
                .unwrap();
        // −2 ln p(y) of the model with the trend, at the latitude moved by u prior σ.
        let drift = SlowDrift::Trend.effect(sigma);
        let with = [effects[0], drift.as_ref()];
        let nominal = widened(&id.trajectory, 3);
        let f = |u: f64| {
            let p = moved(&prep, [u * km.unit[0], 0.0, 0.0]);
            let s = filter_pass(&p, &with, &nominal, &cfg).unwrap();
            neg2_log_evidence(&s.innovations)
        };
        let step = (2.0 * (2.0 / km.hess[(0, 0)]).sqrt()).min(1.0);
        let direct = (f(step) - 2.0 * f(0.0) + f(-step)) / (step * step);
        let formula = hess[(0, 0)];
        assert!(
            (formula / direct - 1.0).abs() < 0.02,
            "H' {formula:.4e} against {direct:.4e} (without the trend {:.4e})",
            km.hess[(0, 0)]
        );
        assert!(
            formula < 0.9 * km.hess[(0, 0)],
            "the trend took nothing away: {formula:.4e} {direct:.4e} {:.4e}",
            km.hess[(0, 0)]
        );
    }
}
