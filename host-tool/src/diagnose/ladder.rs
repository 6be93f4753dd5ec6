//! The model ladder: diagnose, add the effect the evidence chooses, diagnose again — until
//! nothing earns its place or the ladder reaches [`DiagnoseConfig::max_rungs`].

use estimator_core::effects::Effect;

use super::types::{Diagnosis, Rung};
use super::verdict::is_consistent;
use super::{diagnose_identified, model_label, DiagnoseConfig};
use crate::catalog::Catalog;
use crate::identify::{build_model, identify, identify_widened, markov, Identification, Prepared};

/// The 12 drift coefficients of the paper's model come first among the parameters.
const DRIFT_COEFFICIENTS: usize = 12;

/// What the model ladder produces.
pub struct Ladder<'c> {
    /// Every rung's diagnosis, the starting model first.
    pub diagnoses: Vec<Diagnosis>,
    /// The rung summaries (the same order).
    pub rungs: Vec<Rung>,
    /// The final model's identification.
    pub identification: Identification,
    /// The final model's effects (the paper's drift first).
    pub effects: Vec<&'c dyn Effect>,
}

/// The model ladder: start from `start` effects, diagnose, add the effect the evidence chooses,
/// repeat until nothing earns its place (or `max_rungs`).
pub fn ladder<'c>(
    prep: &Prepared,
    catalog: &'c Catalog,
    start: &[&'c dyn Effect],
    cfg: &DiagnoseConfig,
) -> anyhow::Result<Ladder<'c>> {
    ladder_from(prep, catalog, start, cfg, None)
}

/// [`ladder`], its first rung from `first`, the identification of the `start` model on `prep`
/// with `cfg.identify` when it was made already (else fitted here).
pub fn ladder_from<'c>(
    prep: &Prepared,
    catalog: &'c Catalog,
    start: &[&'c dyn Effect],
    cfg: &DiagnoseConfig,
    first: Option<Identification>,
) -> anyhow::Result<Ladder<'c>> {
    let mut effects = start.to_vec();
    let mut diagnoses = vec![];
    let mut rungs: Vec<Rung> = vec![];
    let mut first = first;
    // The rung below's fit: the next rung's model is it with one effect more, fitted from it
    // (as its candidate's refit was, so the memo hands that refit back).
    let mut below: Option<Identification> = None;
    loop {
        // The steps of this rung are noted as `rung k: …`.
        let at = DiagnoseConfig {
            progress: cfg.progress.within(format!("rung {}", rungs.len())),
            ..cfg.clone()
        };
        let id = match first.take() {
            Some(id) => id,
            None => {
                let model = build_model(prep.site, &effects, &cfg.identify)?;
                at.progress
                    .note(|| format!("fitting {}", model_label(&effects)));
                match &below {
                    Some(b) => identify_widened(&model, prep, &cfg.identify, b)?,
                    None => identify(&model, prep, &cfg.identify)?,
                }
            }
        };
        // A rung with `drift-markov`: its σ and τ from the data before it is diagnosed (the
        // candidates' refits keep the catalog's: the choice of effect is unchanged).
        let (tuned, id) = markov::tune(catalog, prep, &effects, &cfg.identify, id)?;
        effects = tuned;
        let (d, id) = diagnose_identified(prep, catalog, &effects, &at, id)?;
        rungs.push(rung(&d, &id));
        let next = if rungs.len() < cfg.max_rungs {
            next_effect(catalog, &d)
        } else {
            None
        };
        diagnoses.push(d);
        let Some((e, p, reason)) = next else {
            return Ok(Ladder {
                diagnoses,
                rungs,
                identification: id,
                effects,
            });
        };
        if let Some(last) = rungs.last_mut() {
            last.next = Some((e.name().to_string(), p));
            last.next_reason = Some(reason);
        }
        effects.push(e);
        below = Some(id);
    }
}

/// The effects the ladder added, in order, and their evidence gain over the starting model: the
/// sum of each rung's chosen refit's gain over the rung before (none when a rung's choice has no
/// refit among its ranking).
pub(crate) fn additions(diagnoses: &[Diagnosis]) -> (Vec<String>, f64) {
    let mut added = vec![];
    let mut gain = 0.0;
    for d in diagnoses {
        let Some(choice) = &d.choice else { continue };
        let refit = d.refit_of(&choice.effect);
        // A choice without a refit on the ranking's scale cannot be put on it: none weighed.
        let Some(r) = refit else {
            return (vec![], 0.0);
        };
        added.push(choice.effect.clone());
        gain += r.evidence_gain;
    }
    (added, gain)
}

/// A stochastic catch-all the data preferred at a rung where a deterministic law was chosen
/// instead ([`super::select::choose`]: a law that explains the data to the noise floor wins).
/// The preference is the ladder's, not the data's, so the final model is weighed against the
/// catch-all in place of the law and of everything added after it: a hidden Gauss–Markov drift
/// (36 h at 30 s) had `g2` chosen over `drift-markov` (gain 666.9 against 723.1), and the result
/// was trusted with a coefficient 3.8 total σ off.
#[derive(Clone, Debug)]
pub(crate) struct Overruled {
    /// The catch-all.
    pub effect: String,
    /// The law chosen at that rung and the later additions, in order.
    pub instead_of: Vec<String>,
    /// Its evidence gain over the final model.
    pub evidence_gain: f64,
    /// The drift coefficients of its refit: name, value, 1σ.
    pub drift: Vec<(&'static str, f64, f64)>,
}

/// The catch-alls the ladder overruled ([`Overruled`]), each on the final model's scale (none
/// when a rung's choice has no refit among its ranking, as in [`additions`]).
pub(crate) fn overruled(diagnoses: &[Diagnosis]) -> Vec<Overruled> {
    let mut chosen = vec![];
    for d in diagnoses {
        let Some(choice) = &d.choice else { continue };
        let Some(law) = d.refit_of(&choice.effect) else {
            return vec![];
        };
        let rival = d
            .refits()
            .filter(|r| super::select::STOCHASTIC.contains(&r.effect.as_str()))
            .filter(|r| r.evidence_gain > law.evidence_gain)
            .max_by(|a, b| a.evidence_gain.total_cmp(&b.evidence_gain));
        chosen.push((choice.effect.clone(), law.evidence_gain, rival));
    }
    let mut out = vec![];
    for (i, (_, _, rival)) in chosen.iter().enumerate() {
        let Some(r) = rival else { continue };
        let later: f64 = chosen[i..].iter().map(|c| c.1).sum();
        out.push(Overruled {
            effect: r.effect.clone(),
            instead_of: chosen[i..].iter().map(|c| c.0.clone()).collect(),
            evidence_gain: r.evidence_gain - later,
            drift: r.drift.clone(),
        });
    }
    out
}

/// The rung of diagnosis `d` with its identification's estimates (no next step yet).
pub(crate) fn rung(d: &Diagnosis, id: &Identification) -> Rung {
    let best = id.best();
    let coefficients = id
        .params
        .iter()
        .take(DRIFT_COEFFICIENTS)
        .enumerate()
        .map(|(k, p)| (p.name.to_string(), best.value[k], best.sigma(k)))
        .collect();
    let effect_params = id
        .params
        .iter()
        .enumerate()
        .skip(DRIFT_COEFFICIENTS)
        .map(|(k, p)| {
            (
                p.name.to_string(),
                p.unit.to_string(),
                best.value[k],
                best.sigma(k),
            )
        })
        .collect();
    Rung {
        model: d.model.clone(),
        residual_rms_over_floor: d.residual_rms_over_floor,
        nis_mean: d.nis_mean,
        whiteness_p: d.whiteness.p_value,
        coefficients,
        effect_params,
        consistent: is_consistent(d),
        next: None,
        next_reason: None,
    }
}

/// The effect the evidence chose in `d`, with its Holm-adjusted p-value and the reason.
fn next_effect<'c>(catalog: &'c Catalog, d: &Diagnosis) -> Option<(&'c dyn Effect, f64, String)> {
    let c = d.choice.as_ref()?;
    let p = d
        .ranking
        .iter()
        .find(|r| r.effect == c.effect)
        .map(|r| r.p_adjusted)
        .unwrap_or(f64::NAN);
    let e = match c.profiled {
        Some(made) => Some(made.effect(catalog)),
        None => catalog.by_name(&c.effect),
    };
    e.map(|e| (e, p, c.reason.clone()))
}
