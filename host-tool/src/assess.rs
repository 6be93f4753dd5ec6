//! The honest 1σ of a final fit and whether to trust it: one path for `identify`, `diagnose`
//! and `report`.
//!
//! 1. The set-up estimated where the data can and marginalised where they cannot
//!    ([`crate::identify::setup::settle`]): the total covariance.
//! 2. Every catalog effect not in the model weighed on the same evidence scale
//!    ([`crate::diagnose::alternatives`]): the plausible ones' spread joins the total 1σ.
//! 3. The reasons not to trust it: the data contradict the stated set-up; the data prefer an
//!    effect the model lacks; a plausible alternative moves a coefficient beyond its total 1σ.

use estimator_core::effects::Effect;

use crate::diagnose::alternatives::{self, Alternative, PLAUSIBLE_MARGIN};
use crate::diagnose::select::MIN_EVIDENCE_GAIN;
use crate::diagnose::DiagnoseConfig;
use crate::identify::setup::{settle, Settled, Uncertainty};
use crate::identify::{Config, Identification, Prepared};

/// A final fit assessed.
pub struct Assessment {
    /// Measurements with the set-up where prior and data put it.
    pub prep: Prepared,
    /// The fit there.
    pub id: Identification,
    /// Noise-only and total 1σ, each source's share.
    pub unc: Uncertainty,
    /// The alternative explanations, by evidence.
    pub alternatives: Vec<Alternative>,
    /// Why not to trust it on these accounts (empty: nothing against it here).
    pub reasons: Vec<String>,
}

/// Assesses the fit `id` of `effects` on `prep` (see the module docs). A single pass is returned
/// as it is, with its own covariance.
pub fn assess(
    effects: &[&'static dyn Effect],
    prep: Prepared,
    cfg: &Config,
    id: Identification,
) -> anyhow::Result<Assessment> {
    let Settled { prep, id, mut unc } = settle(effects, prep, cfg, id)?;
    if id.refined.is_none() {
        return Ok(Assessment {
            prep,
            id,
            unc,
            alternatives: vec![],
            reasons: vec![],
        });
    }
    let dcfg = DiagnoseConfig {
        identify: cfg.clone(),
        ..Default::default()
    };
    let alts = alternatives::weigh(&prep, effects, &dcfg, &id)?;
    unc.add_model_spread(&alternatives::averaging_spread(&alts, id.params.len()));
    let mut reasons = unc.untrusted_reasons();
    reasons.extend(alternatives_untrusted(&alts, &unc, &id));
    Ok(Assessment {
        prep,
        id,
        unc,
        alternatives: alts,
        reasons,
    })
}

/// Why the alternatives make the result untrusted: one the data prefer, or a plausible one that
/// moves a coefficient beyond its total 1σ.
pub fn alternatives_untrusted(
    alts: &[Alternative],
    unc: &Uncertainty,
    id: &Identification,
) -> Vec<String> {
    let best = alts.iter().map(|a| a.evidence_gain).fold(0.0, f64::max);
    let mut out = vec![];
    for a in alts.iter().filter(|a| a.plausible(best)) {
        let worst = (0..a.shift.len())
            .map(|k| (k, a.shift[k] / unc.total_sigma[k]))
            .max_by(|x, y| x.1.abs().total_cmp(&y.1.abs()));
        let Some((k, z)) = worst else { continue };
        if a.evidence_gain > MIN_EVIDENCE_GAIN {
            out.push(format!(
                "the data prefer adding `{}` (evidence gain {:.1}, −2 ln units); with it {} would move by {:+.1}σ — run `driftid diagnose`",
                a.effect, a.evidence_gain, id.params[k].name, z
            ));
        } else if z.abs() > 1.0 {
            out.push(format!(
                "`{}` explains the data almost as well (evidence gain {:.1}, within {PLAUSIBLE_MARGIN} of the best) and would move {} by {:+.1}σ: this run cannot tell them apart — a longer run (a day at least), a second run from another orientation (`driftid plan`) or a bench value of `{}` would",
                a.effect, a.evidence_gain, id.params[k].name, z, a.effect
            ));
        }
    }
    out
}
