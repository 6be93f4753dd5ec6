//! The fit of a larger model warm-started from a nested one's: a candidate effect's refit, the
//! ladder's next rung, a rival weighed with the set-up marginalised. Each adds effects to a model
//! already fitted on the same data; its fit starts where that one ended, the added terms off.

use estimator_core::model::{Model, ANGLES};
use estimator_core::Measurement;
use nalgebra::{DMatrix, DVector};

use super::{
    converged, gauss_newton, identify, memo, neg2_log_evidence, params_of, start_prior, Config,
    GaussNewton, Identification, Prepared,
};

/// `model` — the effects of `nested`'s model and more — fitted on `prep` (where `nested` was
/// fitted) by Gauss–Newton from `nested`'s trajectory, each added state at zero, its prior mean:
/// the nested fit is the larger model's fit with the added terms switched off, a start as near
/// as [`super::identify_from`]'s. The cold fit's two EKF passes and, on a misfit, its
/// continuation check (a fit of its own, windows doubling) are not run: a 60-h refit in 2–5
/// passes where the cold one took 5–8 passes' worth.
///
/// Where the warm start cannot stand for them, [`identify`] fits cold: a state of `nested`
/// missing from `model` or named twice, Gauss–Newton failing, not converging or no longer
/// contracting ([`contracting_passes`]), or a fit whose
/// −2 ln p(y) is above the nested fit's by more than the added states could cost
/// ([`LOST_PER_ADDED_STATE`] each): switching them off again would fit better, so the trajectory
/// was lost.
pub(crate) fn identify_widened(
    model: &Model<'_>,
    prep: &Prepared,
    cfg: &Config,
    nested: &Identification,
) -> anyhow::Result<Identification> {
    let key = memo::widened_key(model, prep, cfg, nested);
    cfg.memo.get_or(key, prep.measurements.len(), || {
        widened_anew(model, prep, cfg, nested)
    })
}

/// [`identify_widened`] without its memo.
fn widened_anew(
    model: &Model<'_>,
    prep: &Prepared,
    cfg: &Config,
    nested: &Identification,
) -> anyhow::Result<Identification> {
    let Some(nominal) = widened_trajectory(model, nested) else {
        return identify(model, prep, cfg);
    };
    let added = model.dim() - ANGLES - nested.params.len();
    let (x0, p0) = start_prior(model, prep, &prep.start_sigma());
    let max = cfg.smoother_iterations + WIDENED_EXTRA_ITERATIONS;
    let bound = neg2_log_evidence(&nested.innovations) + added as f64 * LOST_PER_ADDED_STATE;
    match contracting_passes(model, &prep.measurements, nominal, (&x0, &p0), max) {
        Ok(f) if neg2_log_evidence(&f.innovations) <= bound => {
            converged(model, &prep.measurements, None, f)
        }
        _ => identify(model, prep, cfg),
    }
}

/// Gauss–Newton passes from `nominal` until converged (at least two, at most `max`), as
/// [`gauss_newton`] runs them; else the passes run before giving up: a pass failed, `max` was
/// reached, or a pass after the first moved the states more than the one before (a fit that
/// stops contracting does not converge within the budget: acc-misalign beside an unmodelled g²
/// moved 4.8σ, 2.6σ, 7.2σ, then 35–40σ a pass to the eleventh).
fn contracting_passes(
    model: &Model<'_>,
    meas: &[Measurement],
    nominal: Vec<DVector<f64>>,
    (x0, p0): (&DVector<f64>, &DMatrix<f64>),
    max: usize,
) -> Result<GaussNewton, usize> {
    let mut fit = gauss_newton(model, meas, nominal, x0, p0, 1, 1).map_err(|_| 1_usize)?;
    for pass in 2..=max {
        let before = fit.convergence.last_step_sigma;
        fit = gauss_newton(model, meas, fit.states, x0, p0, 1, 1).map_err(|_| pass)?;
        fit.convergence.iterations = pass;
        if fit.convergence.converged {
            return Ok(fit);
        }
        if fit.convergence.last_step_sigma >= before {
            return Err(pass);
        }
    }
    Err(max)
}

/// Gauss–Newton passes a warm start may take beyond the cold fit's [`Config::smoother_iterations`]
/// before [`identify_widened`] fits cold: one that converges takes 2–5 on a misfit (a 60-h run
/// with a drift trend, 3–6 added states).
const WIDENED_EXTRA_ITERATIONS: usize = 3;

/// The most an added state's Occam factor `ln(1 + σ²J)` can cost a fit in −2 ln p(y) before a
/// warm start is taken as lost ([`identify_widened`]): a prior 10⁶ times the posterior in
/// variance costs ln 10⁶ ≈ 14; twice that. A lost trajectory costs 10⁵ and more (NIS/3 of
/// 10³–10⁹ over 10⁴–10⁵ samples).
const LOST_PER_ADDED_STATE: f64 = 28.0;

/// `nested`'s trajectory in `model`'s states: the angles and each parameter of `nested` where
/// `model` has it (by name), the others at zero. `None` where a name of `nested` is not in
/// `model` or either names one twice.
fn widened_trajectory(model: &Model<'_>, nested: &Identification) -> Option<Vec<DVector<f64>>> {
    let names: Vec<&str> = params_of(model).iter().map(|p| p.name).collect();
    let unique = |v: &[&str]| (1..v.len()).all(|i| !v[..i].contains(&v[i]));
    let old: Vec<&str> = nested.params.iter().map(|p| p.name).collect();
    if !unique(&names) || !unique(&old) || nested.trajectory.is_empty() {
        return None;
    }
    let to: Vec<usize> = old
        .iter()
        .map(|n| names.iter().position(|m| m == n).map(|k| ANGLES + k))
        .collect::<Option<_>>()?;
    Some(
        nested
            .trajectory
            .iter()
            .map(|x| {
                let mut w = DVector::zeros(model.dim());
                w.rows_mut(0, ANGLES).copy_from(&x.rows(0, ANGLES));
                for (k, &i) in to.iter().enumerate() {
                    w[i] = x[ANGLES + k];
                }
                w
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::build_model;
    use crate::simulate::{InjectedEffect, Scenario};

    /// A day at 60 s with an accelerometer bias and a drift trend the paper's model lacks
    /// (a misfit: NIS/3 ≈ 7): its paper fit, the data and the settings.
    fn misfit() -> (Prepared, Config, Identification) {
        let mut sc = Scenario::paper();
        sc.hours = 24.0;
        sc.rate_s = 60.0;
        sc.effects = vec![
            InjectedEffect::AccBias {
                b_mps2: [5e-4, -3e-4, 4e-4],
            },
            InjectedEffect::DriftTrend {
                k_deg_h_per_h: [2e-3, -1e-3, 1.5e-3],
            },
        ];
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let effects = [crate::catalog::paper()];
        let paper = build_model(prep.site, &effects, &cfg).unwrap();
        let nested = identify(&paper, &prep, &cfg).unwrap();
        (prep, cfg, nested)
    }

    fn with(name: &str) -> [&'static dyn estimator_core::effects::Effect; 2] {
        [
            crate::catalog::paper(),
            crate::catalog::builtin(name).unwrap(),
        ]
    }

    /// Each candidate's fit warm-started from the paper's is its cold fit (the single pass, the
    /// second, Gauss–Newton, the continuation check): −2 ln p(y) within 0.05 and every parameter
    /// within 0.02 of its 1σ. Both stop when a pass moves no state by 0.01σ
    /// ([`super::super::GN_TOLERANCE_SIGMA`]), so the two differ by about that much; a start
    /// mapped onto the wrong states, or the added ones not at zero, would differ by many σ or
    /// fall back to the cold fit (caught by `single_pass`).
    #[test]
    fn a_widened_fit_is_the_cold_fit() {
        let (prep, cfg, nested) = misfit();
        for name in ["acc-bias", "drift-trend", "g2", "acc-scale"] {
            let effects = with(name);
            let model = build_model(prep.site, &effects, &cfg).unwrap();
            let warm = identify_widened(&model, &prep, &cfg, &nested).unwrap();
            let cold = identify(&model, &prep, &cfg).unwrap();
            assert!(warm.single_pass.is_none(), "{name}: fitted cold");
            assert!(cold.single_pass.is_some());
            let de = neg2_log_evidence(&warm.innovations) - neg2_log_evidence(&cold.innovations);
            assert!(de.abs() < 0.05, "{name}: −2 ln p(y) differs by {de}");
            let (w, c) = (warm.best(), cold.best());
            for k in 0..c.value.len() {
                let z = (w.value[k] - c.value[k]).abs() / c.sigma(k);
                assert!(z < 0.02, "{name} {}: {z:.4}σ apart", cold.params[k].name);
                let r = w.sigma(k) / c.sigma(k) - 1.0;
                assert!(
                    r.abs() < 1e-3,
                    "{name} {}: 1σ {r:+.2e} apart",
                    cold.params[k].name
                );
            }
        }
    }

    /// Where the warm start cannot stand for the cold fit, the cold fit is what comes back, bit
    /// for bit: a nested fit with a state the larger model lacks (no map of its trajectory), and
    /// one that claims a fit the larger model cannot reach (its innovations' NIS zeroed, so
    /// −2 ln p(y) below the warm fit's by ~3 per sample: the lost trajectory's test).
    #[test]
    fn the_cold_fit_stands_where_the_warm_start_cannot() {
        let (prep, cfg, nested) = misfit();
        let effects = with("acc-bias");
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let cold = identify(&model, &prep, &cfg).unwrap();
        let same = |id: &Identification| {
            id.single_pass.is_some()
                && neg2_log_evidence(&id.innovations).to_bits()
                    == neg2_log_evidence(&cold.innovations).to_bits()
                && id.best().value == cold.best().value
        };
        let scaled = with("acc-scale");
        let scale = build_model(prep.site, &scaled, &cfg).unwrap();
        let other = identify(&scale, &prep, &cfg).unwrap();
        let unmapped = identify_widened(&model, &prep, &cfg, &other).unwrap();
        assert!(
            same(&unmapped),
            "a start with acc-scale's states was mapped"
        );
        let mut claims = nested.clone();
        for r in &mut claims.innovations {
            r.nis = 0.0;
        }
        let lost = identify_widened(&model, &prep, &cfg, &claims).unwrap();
        assert!(same(&lost), "a fit far above its nested start was kept");
    }

    /// A fit that stops contracting is given up before the budget, not run to it: acc-misalign
    /// beside an unmodelled g² (a day at 60 s) moves its states more at the third pass than at
    /// the second, and its cold fit ends 11 passes later still moving by ~100σ a pass. The warm
    /// start hands over to it after at most 4 of the 6 passes it may take.
    #[test]
    fn a_fit_that_stops_contracting_is_given_up_early() {
        let sc = crate::simulate::g2_and_acc_bias_day();
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let paper = [crate::catalog::paper()];
        let nested = identify(&build_model(prep.site, &paper, &cfg).unwrap(), &prep, &cfg).unwrap();
        let effects = with("acc-misalign");
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let nominal = widened_trajectory(&model, &nested).unwrap();
        let (x0, p0) = start_prior(&model, &prep, &prep.start_sigma());
        let passes = contracting_passes(&model, &prep.measurements, nominal, (&x0, &p0), 6);
        assert!(
            matches!(passes, Err(k) if k <= 4),
            "{:?}",
            passes.map(|f| f.convergence)
        );
        let cold = identify(&model, &prep, &cfg).unwrap();
        assert!(
            cold.convergence.is_some_and(|c| !c.converged),
            "the cold fit converged"
        );
    }
}
