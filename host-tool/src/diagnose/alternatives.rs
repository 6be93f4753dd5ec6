//! Every catalog effect not in the model as an alternative explanation of the same data, on one
//! evidence scale with the model itself, and what each would do to the coefficients.
//!
//! From the one replay of the score tests ([`super::score`]) each candidate's parameters β have,
//! to first order about the current fit, a Gaussian likelihood with information `I` and score
//! `s`, and a prior `N(0, Σ)` (the effect's `prior_sigma`). Then, exactly for the linearised
//! model:
//!
//! ```text
//! posterior  C = (I + Σ⁻¹)⁻¹,  β̂ = C s
//! evidence gain (−2 ln units, positive: the data prefer adding it)
//!            G = sᵀ C s − ln det(1 + Σ^½ I Σ^½)
//! the coefficients under it  Δ = Ψ_N β̂    (Ψ_N β: how far β, unmodelled, pulls the estimate
//!                                           from the truth the refit with it recovers)
//! ```
//!
//! `G` is the quantity the refits' evidence gain measures ([`super::select`]), without refitting;
//! the `ln det` term is the Occam factor. An alternative within [`PLAUSIBLE_MARGIN`] of the best
//! explanation is plausible: the coefficients are averaged over the plausible models (weights
//! `e^{G/2}`), and their spread joins the total 1σ. The *reach* of an alternative is how far it
//! could move a coefficient at a size the run cannot rule out, `|Δ| + 2·√(S C Sᵀ)` — the
//! consider analysis: a coefficient an absent effect could move beyond its total 1σ holds only on
//! that effect's absence.

use estimator_core::effects::Effect;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::candidates::{setups, Setup};
use super::DiagnoseConfig;
use crate::catalog::Catalog;
use crate::identify::{build_model, Identification, Prepared};

/// Evidence (−2 ln units) within which an explanation stays plausible: 6 is "strong" evidence
/// against on the Kass–Raftery scale (a Bayes factor of 20); a weaker one cannot dismiss it.
pub(crate) const PLAUSIBLE_MARGIN: f64 = 6.0;

/// One alternative explanation.
#[derive(Clone, Debug, Serialize)]
pub struct Alternative {
    /// Catalog name of the effect that would be added.
    pub effect: String,
    /// Evidence gain of adding it (−2 ln units; positive: the data prefer it).
    pub evidence_gain: f64,
    /// Its weight among the plausible models (0 when not plausible).
    pub weight: f64,
    /// The model's parameters under it minus the current estimate (state order after the angles).
    pub shift: Vec<f64>,
    /// The 1σ of that shift itself, per parameter: its own parameters are known only to their
    /// posterior under it, carried to the model's (`√diag(Ψ C Ψᵀ)`; for a misstated knob, the
    /// knob's 1σ times the parameter's sensitivity to it).
    pub move_sigma: Vec<f64>,
    /// How far it could move each parameter at a size this run cannot rule out: `|shift| + 2·move_sigma`.
    pub reach: Vec<f64>,
    /// For a misstated set-up ([`crate::diagnose::misstated`]): where the data put the knob.
    pub misstated: Option<Misstated>,
    /// The effect fitted at the set-up as stated, instead of where the data moved it within its
    /// priors: a rival of that move ([`crate::assess`]).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub instead_of_setup: bool,
    /// A misstatement weighed on the starting fit, instead of the effects the ladder then added
    /// (named here): a rival of them all ([`crate::assess::AtTheStart`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub instead_of: Option<String>,
}

/// A set-up value the data give under the hypothesis that it was misstated.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Misstated {
    /// `latitude`, `clock rate` or `gravity`.
    pub knob: &'static str,
    /// Its unit (`deg`, `ppm`).
    pub unit: &'static str,
    /// The stated value.
    pub stated: f64,
    /// The data's value under the broad prior.
    pub value: f64,
    /// Its 1σ.
    pub sigma: f64,
    /// Index of the knob (0 latitude, 1 clock rate, 2 gravity).
    #[serde(skip)]
    pub index: usize,
}

impl Alternative {
    /// An alternative with its shift and the shift's 1σ (weight 0 until [`weight`] sets it; the
    /// reach follows from the two).
    pub(crate) fn new(
        effect: String,
        evidence_gain: f64,
        shift: Vec<f64>,
        move_sigma: Vec<f64>,
        misstated: Option<Misstated>,
    ) -> Self {
        let reach = shift
            .iter()
            .zip(&move_sigma)
            .map(|(s, m)| s.abs() + 2.0 * m)
            .collect();
        Self {
            effect,
            evidence_gain,
            weight: 0.0,
            shift,
            move_sigma,
            reach,
            misstated,
            instead_of_setup: false,
            instead_of: None,
        }
    }

    /// Its name as printed: the effect, and what it would replace where it is a rival of a move
    /// of the set-up or of the ladder's additions.
    pub(crate) fn label(&self) -> String {
        match (&self.instead_of, self.instead_of_setup) {
            (Some(added), _) => format!("{} instead of {added}", self.effect),
            (None, true) => format!("{} at the set-up as stated", self.effect),
            (None, false) => self.effect.clone(),
        }
    }

    /// Whether it is within [`PLAUSIBLE_MARGIN`] of the best explanation (`best_gain`: the
    /// largest gain, 0 when the current model is best).
    pub(crate) fn plausible(&self, best_gain: f64) -> bool {
        self.evidence_gain > best_gain - PLAUSIBLE_MARGIN
    }

    /// The parameters it could move beyond their total 1σ (`total_sigma`) at a size the run
    /// cannot rule out, with that reach in total 1σ: those that hold only on its absence.
    pub(crate) fn reaches_beyond(&self, total_sigma: &[f64]) -> Vec<(usize, f64)> {
        self.reach
            .iter()
            .zip(total_sigma)
            .enumerate()
            .filter(|(_, (r, s))| *r > *s)
            .map(|(k, (r, s))| (k, r / s))
            .collect()
    }
}

/// What a result holds on, from each parameter's name and [`conditional_on`]: every alternative
/// named once with how many of the paper's drift coefficients it could move beyond their total
/// 1σ (the other parameters are not counted) and its largest reach (total 1σ), the
/// farthest-reaching first.
pub(crate) fn held_on<'a>(
    per_parameter: impl IntoIterator<Item = (&'a str, &'a [(String, f64)])>,
) -> Vec<(&'a str, usize, f64)> {
    let paper = crate::catalog::paper().params();
    let mut on: Vec<(&str, usize, f64)> = vec![];
    for (_, conditional) in per_parameter
        .into_iter()
        .filter(|(name, _)| paper.iter().any(|p| p.name == *name))
    {
        for (effect, z) in conditional {
            match on.iter_mut().find(|(e, _, _)| e == effect) {
                Some(x) => {
                    x.1 += 1;
                    x.2 = x.2.max(*z);
                }
                None => on.push((effect, 1, *z)),
            }
        }
    }
    on.sort_by(|a, b| b.2.total_cmp(&a.2));
    on
}

/// "g2 (12 drift coefficients, up to 160.0σ), …" for the three farthest-reaching of [`held_on`]
/// (and how many more); `None` when it holds on nothing.
pub(crate) fn held_on_words(on: &[(&str, usize, f64)]) -> Option<String> {
    if on.is_empty() {
        return None;
    }
    let listed: Vec<String> = on
        .iter()
        .take(3)
        .map(|(e, n, z)| {
            format!(
                "{e} ({n} drift coefficient{}, up to {z:.1}σ)",
                if *n == 1 { "" } else { "s" }
            )
        })
        .collect();
    let more = if on.len() > 3 {
        format!(", and {} more", on.len() - 3)
    } else {
        String::new()
    };
    Some(listed.join(", ") + &more)
}

/// The alternatives parameter `k` holds only on the absence of ([`Alternative::reaches_beyond`]),
/// each named once with its largest reach in total 1σ, the farthest first.
pub(crate) fn conditional_on(
    alts: &[Alternative],
    total_sigma: &[f64],
    k: usize,
) -> Vec<(String, f64)> {
    let mut out: Vec<(String, f64)> = vec![];
    for a in alts {
        let Some(&(_, z)) = a.reaches_beyond(total_sigma).iter().find(|(i, _)| *i == k) else {
            continue;
        };
        match out.iter_mut().find(|(e, _)| *e == a.effect) {
            Some(seen) => seen.1 = seen.1.max(z),
            None => out.push((a.effect.clone(), z)),
        }
    }
    out.sort_by(|a, b| b.1.total_cmp(&a.1));
    out
}

/// The alternatives to the model of `effects` fitted as `id` on `prep`.
pub(crate) fn weigh(
    prep: &Prepared,
    catalog: &Catalog,
    effects: &[&dyn Effect],
    cfg: &DiagnoseConfig,
    id: &Identification,
) -> anyhow::Result<Vec<Alternative>> {
    let model = build_model(prep.site, effects, &cfg.identify)?;
    let run_s = prep.measurements.last().map_or(0.0, |m| m.t_s);
    let has_temp = super::temp_varies(&prep.measurements);
    let setups = setups(catalog, effects, model.dim(), run_s, has_temp, cfg);
    weigh_setups(prep, &model, effects, &setups, cfg, id)
}

/// The candidates `setups` from one replay of `model`'s fit ([`super::replay`], remembered).
fn weigh_setups(
    prep: &Prepared,
    model: &estimator_core::model::Model<'_>,
    effects: &[&dyn Effect],
    setups: &[Setup],
    cfg: &DiagnoseConfig,
    id: &Identification,
) -> anyhow::Result<Vec<Alternative>> {
    let replayed = super::replay(prep, model, effects, setups, id, cfg)?;
    let sigs = &replayed.1;
    let n = model.dim() - estimator_core::model::ANGLES;
    let mut out: Vec<Alternative> = setups
        .iter()
        .zip(sigs)
        .filter_map(|(setup, sig)| Some(alternative(setup, sig.as_ref()?, n)))
        .collect();
    weight(&mut out);
    Ok(out)
}

/// Sets each alternative's model-averaging weight `e^{G/2}` among the plausible ones and the
/// current model (gain 0), and sorts them by evidence, best first.
pub(crate) fn weight(alts: &mut [Alternative]) {
    let best = alts.iter().map(|a| a.evidence_gain).fold(0.0, f64::max);
    let norm: f64 = (-best / 2.0).exp()
        + alts
            .iter()
            .filter(|a| a.plausible(best))
            .map(|a| ((a.evidence_gain - best) / 2.0).exp())
            .sum::<f64>();
    for a in alts.iter_mut() {
        a.weight = if a.plausible(best) {
            ((a.evidence_gain - best) / 2.0).exp() / norm
        } else {
            0.0
        };
    }
    alts.sort_by(|a, b| b.evidence_gain.total_cmp(&a.evidence_gain));
}

/// One candidate's evidence gain, shift and reach (see the module docs).
fn alternative(setup: &Setup, sig: &super::score::Signature, n: usize) -> Alternative {
    let effect = setup.scored();
    let q = sig.q;
    let prior: Vec<f64> = (0..q).map(|k| effect.prior_sigma(k)).collect();
    // Σ^½ I Σ^½ and the posterior in the prior's scale, where both terms are O(1).
    let scaled_info = DMatrix::from_fn(q, q, |a, b| prior[a] * sig.info[(a, b)] * prior[b]);
    let a = &scaled_info + DMatrix::identity(q, q);
    let (c_scaled, ln_det) = match a.clone().cholesky() {
        Some(ch) => {
            let ln_det = 2.0 * ch.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
            (ch.inverse(), ln_det)
        }
        None => (DMatrix::identity(q, q), 0.0),
    };
    let s_scaled = DVector::from_fn(q, |k, _| prior[k] * sig.score[k]);
    let beta_scaled = &c_scaled * &s_scaled;
    let gain = s_scaled.dot(&beta_scaled) - ln_det;
    let beta = DVector::from_fn(q, |k, _| prior[k] * beta_scaled[k]);
    let cov = DMatrix::from_fn(q, q, |a, b| prior[a] * c_scaled[(a, b)] * prior[b]);
    // Rows of the parameters (after the angles) of Ψ: refitting with β moves the estimate by
    // +Ψ β (checked against the refit: tests/honest_uncertainty.rs).
    let sens = sig
        .psi_final
        .view((estimator_core::model::ANGLES, 0), (n, q))
        .into_owned();
    let shift = &sens * &beta;
    let spread = (&sens * &cov * sens.transpose()).diagonal();
    Alternative::new(
        setup.name.to_string(),
        gain,
        shift.iter().copied().collect(),
        spread.iter().map(|v| v.max(0.0).sqrt()).collect(),
        None,
    )
}

/// The 1σ per parameter that averaging over the plausible models (the current one with zero
/// shift) adds to the current model's: the spread of their shifts about the average, and each
/// one's own extra uncertainty (its shift's 1σ) at its weight,
///
/// ```text
/// Var_avg − Var_0 = Σ_k w_k (Δ_k − Δ̄)² + w_0 Δ̄² + Σ_k w_k σ_Δk²
/// ```
///
/// the law of total variance over the models. Without the last term a daily drift that the data
/// disfavour by only 3 (weight 0.16), and that would widen a day-long run's DXz eightfold, left
/// it trusted at 3.6 total σ from the truth (a 30-h periodic drift, outside the catalog).
pub(crate) fn averaging_spread(alts: &[Alternative], n: usize) -> Vec<f64> {
    let mean: Vec<f64> = (0..n)
        .map(|i| alts.iter().map(|a| a.weight * a.shift[i]).sum())
        .collect();
    let w0 = 1.0 - alts.iter().map(|a| a.weight).sum::<f64>();
    (0..n)
        .map(|i| {
            let v = w0 * mean[i] * mean[i]
                + alts
                    .iter()
                    .map(|a| a.weight * ((a.shift[i] - mean[i]).powi(2) + a.move_sigma[i].powi(2)))
                    .sum::<f64>();
            v.sqrt()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each alternative once, counted over the drift coefficients it reaches (an added effect's
    /// parameter, BAx, not counted), with its largest reach, the farthest first; the words list
    /// three and count the rest.
    #[test]
    fn what_a_result_holds_on_is_each_alternative_once_farthest_first() {
        let c = |v: &[(&str, f64)]| -> Vec<(String, f64)> {
            v.iter().map(|(e, z)| (e.to_string(), *z)).collect()
        };
        let per = [
            ("DX0", c(&[("g2", 100.0), ("drift-daily", 2.0)])),
            ("DXx", c(&[])),
            (
                "DZy",
                c(&[
                    ("drift-daily", 14.7),
                    ("g2", 73.4),
                    ("clock rate misstated", 1.5),
                ]),
            ),
            ("DYz", c(&[("acc-scale", 1.2)])),
            ("BAx", c(&[("acc-misalign", 178.8)])),
        ];
        let on = held_on(per.iter().map(|(n, c)| (*n, c.as_slice())));
        assert_eq!(
            on,
            vec![
                ("g2", 2, 100.0),
                ("drift-daily", 2, 14.7),
                ("clock rate misstated", 1, 1.5),
                ("acc-scale", 1, 1.2),
            ]
        );
        assert_eq!(
            held_on_words(&on).unwrap(),
            "g2 (2 drift coefficients, up to 100.0σ), drift-daily (2 drift coefficients, up to \
             14.7σ), clock rate misstated (1 drift coefficient, up to 1.5σ), and 1 more"
        );
        assert_eq!(held_on_words(&[]), None);
    }

    /// The averaged models' variance is a Gaussian mixture's: the current model (shift 0, its
    /// own variance σ0²) and each plausible alternative (shift Δ_k, variance σ0² + σ_Δk²) at their
    /// weights. `averaging_spread` is what the mixture adds to σ0², computed here from the
    /// mixture's definition E[x²] − E[x]² (an independent expression; equal to rounding, 1e-12).
    /// An implausible alternative (weight 0) adds nothing.
    #[test]
    fn averaging_adds_the_mixture_variance_of_the_plausible_models() {
        let alt = |gain: f64, shift: [f64; 2], move_sigma: [f64; 2]| {
            Alternative::new("e".into(), gain, shift.to_vec(), move_sigma.to_vec(), None)
        };
        let mut alts = vec![
            alt(-3.3, [2.0, -0.5], [8.0, 0.1]),
            alt(1.0, [-1.0, 0.3], [0.5, 0.2]),
            alt(-40.0, [100.0, 100.0], [100.0, 100.0]),
        ];
        weight(&mut alts);
        assert_eq!(alts[2].weight, 0.0);
        let spread = averaging_spread(&alts, 2);
        let w0 = 1.0 - alts.iter().map(|a| a.weight).sum::<f64>();
        let sigma0 = 1.0;
        for i in 0..2 {
            let (mut m1, mut m2) = (0.0, w0 * sigma0 * sigma0);
            for a in &alts {
                m1 += a.weight * a.shift[i];
                m2 += a.weight * (sigma0 * sigma0 + a.move_sigma[i].powi(2) + a.shift[i].powi(2));
            }
            let added = m2 - m1 * m1 - sigma0 * sigma0;
            assert!(
                (spread[i].powi(2) - added).abs() < 1e-12,
                "{i}: {spread:?} vs {added}"
            );
        }
        // The −3.3 alternative's own variance dominates x: the shifts alone spread it by < 1.4.
        let shifts_only: Vec<Alternative> = alts
            .iter()
            .map(|a| Alternative {
                move_sigma: vec![0.0; 2],
                ..a.clone()
            })
            .collect();
        let without = averaging_spread(&shifts_only, 2);
        assert!(
            spread[0] > 2.0 && without[0] < 1.4,
            "{spread:?} {without:?}"
        );
    }
}
