//! The honest 1σ of a final fit and whether to trust it: one path for `identify`, `diagnose`
//! and `report`.
//!
//! 1. The set-up estimated where the data can and marginalised where they cannot
//!    ([`crate::identify::setup::settle`]): the total covariance.
//! 2. Every catalog effect not in the model weighed on the same evidence scale
//!    ([`crate::diagnose::alternatives`]): the plausible ones' spread joins the total 1σ.
//! 3. A gyro drift step that beats every explanation is repaired ([`repaired_if_it_wins`]).
//! 4. The reasons not to trust it: the data contradict the stated set-up; the data prefer an
//!    effect the model lacks; a plausible alternative moves a coefficient beyond its total 1σ.

use crate::steps::Progress;
use estimator_core::effects::Effect;
use rayon::prelude::*;

use crate::catalog::Catalog;
use crate::diagnose::alternatives::{self, Alternative, PLAUSIBLE_MARGIN};
use crate::diagnose::drift_step::{self, DriftStepFit};
use crate::diagnose::misstated;
use crate::diagnose::select::{CONFOUNDED_MARGIN, MIN_EVIDENCE_GAIN};
use crate::diagnose::DiagnoseConfig;
use crate::identify::setup::{
    settle_about, uncertainty_reusing, Computed, Settled, SetupPriors, Uncertainty,
};
use crate::identify::slow_drift::SlowDrift;
use crate::identify::{build_model, identify_from, Config, Identification, Prepared};

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
    /// The settings it was assessed with (a repaired misstatement's prior is the data's 1σ).
    pub cfg: Config,
    /// The evidence gain of the set-up moved within its priors over the set-up as stated
    /// (`None`: the data did not move it).
    pub moved: Option<f64>,
}

/// Where an alternative's shift of the coefficients is judged: against the fit's own total 1σ,
/// or, for a run of a joint fit, carried into the joint estimate (`weight`, the run's share of
/// it: [`crate::identify::joint::RunFit::weight`]) and judged against the joint total 1σ.
pub(crate) struct Scale<'a> {
    /// How a shift of the run's estimate moves the estimate judged (`None`: itself).
    pub weight: Option<&'a nalgebra::DMatrix<f64>>,
    /// The total 1σ the moved estimate is judged against.
    pub total_sigma: &'a [f64],
}

impl Scale<'_> {
    /// The shift `shift` of the run's estimate in total 1σ of the estimate judged.
    fn z(&self, shift: &[f64]) -> Vec<f64> {
        let moved = match self.weight {
            Some(w) => (w * nalgebra::DVector::from_column_slice(shift))
                .as_slice()
                .to_vec(),
            None => shift.to_vec(),
        };
        moved
            .iter()
            .zip(self.total_sigma)
            .map(|(d, s)| d / s)
            .collect()
    }

    /// The coefficient `shift` moves most, and by how many total 1σ.
    fn worst(&self, shift: &[f64]) -> Option<(usize, f64)> {
        self.z(shift)
            .into_iter()
            .enumerate()
            .max_by(|x, y| x.1.abs().total_cmp(&y.1.abs()))
    }
}

impl Assessment {
    /// Why not to trust the fit, its alternatives' shifts judged on `scale`: the data contradict
    /// the stated set-up; the data prefer an effect the model lacks; a plausible alternative
    /// moves a coefficient beyond the total 1σ; the result rests on an assumed set-up prior.
    pub(crate) fn reasons_on(&self, scale: &Scale<'_>) -> Vec<String> {
        let judged = Judged {
            alternatives: self.alternatives.clone(),
            unc: self.unc.clone(),
            moved: self.moved,
            priors: self.cfg.setup,
        };
        judged.reasons(&self.id, scale)
    }
}

/// What an assessment's reasons not to trust are drawn from, kept to judge them again on
/// another scale (a joint fit's, [`Scale`]).
#[derive(Clone)]
pub(crate) struct Judged {
    /// The alternatives weighed ([`Assessment::alternatives`]).
    pub alternatives: Vec<Alternative>,
    /// The fit's uncertainty ([`Assessment::unc`]).
    pub unc: Uncertainty,
    /// [`Assessment::moved`].
    pub moved: Option<f64>,
    /// The set-up priors the fit was assessed with.
    pub priors: SetupPriors,
}

impl Judged {
    /// See [`Assessment::reasons_on`]; `id` the fit assessed.
    pub(crate) fn reasons(&self, id: &Identification, scale: &Scale<'_>) -> Vec<String> {
        let mut reasons = self.unc.untrusted_reasons();
        reasons.extend(alternatives_untrusted(
            &self.alternatives,
            &self.unc,
            id,
            scale,
        ));
        if let Some(g0) = self.moved {
            reasons.extend(move_confounded(
                &self.alternatives,
                g0,
                id,
                &self.priors,
                scale,
            ));
        }
        reasons
    }
}

/// Assesses the fit `id` of `effects` on `prep` (see the module docs). A single pass is returned
/// as it is, with its own covariance. A misstated set-up that beats every other explanation
/// ([`misstated::to_repair`]) is repaired, named among the findings, and the model refitted and
/// assessed there (once).
pub fn assess(
    catalog: &Catalog,
    effects: &[&dyn Effect],
    prep: Prepared,
    cfg: &Config,
    id: Identification,
) -> anyhow::Result<Assessment> {
    assess_with(catalog, effects, prep, cfg, id, None, &Progress::default())
}

/// [`assess`], its steps noted to `progress` (the set-up, the alternatives, a repair); `known`:
/// the set-up's uncertainty computed before, reused if it is this fit's ([`Computed`]).
pub(crate) fn assess_with<'c>(
    catalog: &'c Catalog,
    effects: &[&'c dyn Effect],
    prep: Prepared,
    cfg: &Config,
    id: Identification,
    known: Option<&Computed>,
    progress: &Progress,
) -> anyhow::Result<Assessment> {
    let (first, repair) =
        assess_as_stated(catalog, effects, (prep, id), cfg, (true, known), progress)?;
    let Some((prep, cfg, start)) = repair else {
        return Ok(first);
    };
    progress.note(|| "refitting at the repaired set-up".into());
    let model = build_model(prep.site, effects, &cfg)?;
    // Warm, else cold; where neither converges (a 60-h run at 29° N stated as 32°: the smoother's
    // innovation covariance not positive definite at the repaired latitude) the stated set-up's
    // numbers stand, not trusted, with the misstatement named — not a refusal.
    let id = match refit_repaired(&model, &prep, &cfg, &start) {
        Ok(id) => id,
        Err(e) => return Ok(unrepaired(first, &prep, &e)),
    };
    // A wander tuned at the stated set-up is tuned again at the repaired one, as the
    // misstatement was weighed ([`misstated`]); where that fails the wander stays as tuned.
    // Callers read the effects back with [`Catalog::as_tuned`].
    let (effects, id) =
        match crate::identify::markov::tune(catalog, &prep, effects, &cfg, id.clone()) {
            Ok(tuned) => tuned,
            Err(_) => (effects.to_vec(), id),
        };
    let (mut again, _) =
        assess_as_stated(catalog, &effects, (prep, id), &cfg, (false, None), progress)?;
    again.cfg = cfg;
    Ok(again)
}

/// The stated set-up's assessment `first` where the model could not be fitted at the set-up
/// the data put it at (`repaired`, `err`): its numbers stand, not trusted, with the misstatement
/// named.
fn unrepaired(mut first: Assessment, repaired: &Prepared, err: &anyhow::Error) -> Assessment {
    first.reasons.push(format!(
        "{}: the estimate is the stated set-up's — correct the metadata and run again",
        unfitted_repair(&first.prep, repaired, err)
    ));
    first
}

/// The model refitted at a repaired set-up `prep`: warm from `start`, else cold (the warm start,
/// a fit at the stated set-up, can lie where the smoother diverges: 60 h at 29° N stated as 32°).
pub(crate) fn refit_repaired(
    model: &estimator_core::model::Model<'_>,
    prep: &Prepared,
    cfg: &Config,
    start: &Identification,
) -> anyhow::Result<Identification> {
    identify_from(model, prep, cfg, start).or_else(|_| crate::identify::identify(model, prep, cfg))
}

/// The data put the set-up elsewhere (`repaired`, `stated` as given), and the model could not
/// be fitted there (`err`).
pub(crate) fn unfitted_repair(
    stated: &Prepared,
    repaired: &Prepared,
    err: &anyhow::Error,
) -> String {
    let (l0, l1) = (
        stated.site.latitude_rad.to_degrees(),
        repaired.site.latitude_rad.to_degrees(),
    );
    let at = if (l1 - l0).abs() > 1e-9 {
        format!(
            " (latitude {l1:.4} deg where {} is stated)",
            (l0 * 1e9).round() / 1e9
        )
    } else {
        String::new()
    };
    format!(
        "the data put the set-up elsewhere{at}, but the model could not be fitted there \
         ({err:#})"
    )
}

/// A misstated set-up to repair: the repaired measurements and settings, and the fit to start
/// from.
type Repair = (Prepared, Config, Identification);

/// [`assess`] with the set-up as `prep` and `cfg` state it; with the repaired set-up and the
/// fit to start from where a misstatement is to be repaired (and `may_repair`).
fn assess_as_stated(
    catalog: &Catalog,
    effects: &[&dyn Effect],
    (prep, id): (Prepared, Identification),
    cfg: &Config,
    (may_repair, known): (bool, Option<&Computed>),
    progress: &Progress,
) -> anyhow::Result<(Assessment, Option<Repair>)> {
    let stated = (prep.clone(), id.clone());
    progress.note(|| "the set-up's uncertainty".into());
    let about = uncertainty_reusing(effects, &prep, cfg, &id, known)?;
    let dcfg = DiagnoseConfig {
        identify: cfg.clone(),
        progress: progress.clone(),
        ..Default::default()
    };
    // Side by side: the misstatements' refits about the stated set-up (they need `about`
    // alone), beside the refit at the set-up's posterior and the catalog's replay on that refit
    // (one thread's work: its candidates step with the pass). The stated set-up with its priors
    // is refitted where the set-up's posterior puts it — where `settle` refits: that refit
    // then serves both (the same passes from the same nominal: the same bits).
    // Weighed and settled before about this fit (`diagnose`'s starting fit, when the ladder
    // added nothing).
    let reused = known
        .and_then(|k| k.misstated_for(effects, &stated.0, cfg, &stated.1))
        .cloned();
    let kept_fit = known
        .and_then(|k| k.settling_for(effects, &stated.0, cfg, &stated.1))
        .cloned();
    let shared = crate::identify::setup::settling_refit(&about)
        .is_some_and(|d| Some(d) == misstated::priors_refit_at(&about));
    let (settled, refits) = rayon::join(
        || -> anyhow::Result<_> {
            let settled = settle_about(effects, prep, cfg, id, about.clone(), kept_fit)?;
            if settled.id.refined.is_none() {
                return Ok((settled, None));
            }
            progress.note(|| "weighing the catalog effects not in the model".into());
            let alts = alternatives::weigh(&settled.prep, catalog, effects, &dcfg, &settled.id)?;
            Ok((settled, Some(alts)))
        },
        || {
            progress.note(|| "weighing a misstated latitude, clock rate or gravity".into());
            match reused {
                Some(_) => Ok(None),
                None => misstated::refits(effects, &stated.0, cfg, &stated.1, &about, shared),
            }
        },
    );
    let (settled, alts) = settled?;
    let weighed = refits.and_then(|r| match (r, reused) {
        (_, Some(w)) => Ok(w),
        (Some(r), None) => r.weigh(
            effects,
            &stated.0,
            cfg,
            (&stated.1, &about),
            settled.at_posterior.clone().filter(|_| shared),
        ),
        (None, None) => Ok(misstated::Weighed::none()),
    });
    let Settled {
        prep, id, mut unc, ..
    } = settled;
    let mut out = Assessment {
        prep,
        id,
        unc: Uncertainty::exact(&nalgebra::DMatrix::zeros(0, 0)),
        alternatives: vec![],
        reasons: vec![],
        cfg: cfg.clone(),
        moved: None,
    };
    // A single pass: its own covariance, nothing weighed.
    let Some(alts) = alts else {
        out.unc = unc;
        return Ok((out, None));
    };
    let (mut alts, weighed) = (alts, weighed?);
    // The data prefer the set-up moved within its priors to the set-up as stated.
    let moved = weighed.stated_gain.filter(|g| *g > 0.0);
    let within_priors = weighed.within_priors;
    // (The misstatements' shifts are taken about the refit where the stated priors put the
    // set-up, which `settle` ends at.)
    alts.extend(weighed.alternatives);
    if let Some(g0) = moved {
        let to_final = offset(&stated.1, &out.id);
        alts.extend(rivals_of_the_move(
            catalog, effects, &stated, &dcfg, g0, &to_final,
        )?);
    }
    alternatives::weight(&mut alts);
    // Whether or not the data contradict the stated set-up, a repair must beat the catalog's
    // effects with the set-up within its priors (a clock "4367 ppm fast" beat the set-up moved
    // within its priors by 26, and effects refitted with the set-up as stated, while acc-bias
    // and a trend with it moved explained more).
    let rivals = match within_priors {
        Some(w) if may_repair && misstated::to_repair(&alts, &[]).is_some() => {
            progress
                .note(|| "weighing the catalog effects with the set-up within its priors".into());
            rivals_within_priors(catalog, effects, &stated, &dcfg, w)?
        }
        _ => vec![],
    };
    let repair = misstated::to_repair(&alts, &rivals).filter(|_| may_repair);
    // Whole even where a repair follows: it is what stands, not trusted, where the model cannot
    // be fitted at the repaired set-up ([`assess_with`]; an empty 1σ there ended `identify` in
    // a panic printing it).
    unc.add_model_spread(&alternatives::averaging_spread(&alts, out.id.params.len()));
    out.unc = unc;
    out.alternatives = alts;
    out.moved = moved;
    out.reasons = out.reasons_on(&Scale {
        weight: None,
        total_sigma: &out.unc.total_sigma,
    });
    let repair = repair.map(|m| {
        let (p, c) = misstated::repair(&stated.0, cfg, &m, &out.alternatives, &[]);
        (p, c, stated.1)
    });
    Ok((out, repair))
}

/// The misstated set-ups weighed on the starting fit where the ladder then climbed from the
/// set-up as stated ([`crate::cli::common::starting_fit`]): each is a rival of everything the
/// ladder adds. A clock 1000 ppm fast explained a 60-h run's misfit better than a drift trend (by
/// 8.3 at the start), the ladder added the trend (it weighs catalog effects), the trend absorbed
/// the clock's signature, and the final model, weighed against a misstated clock *on top of* the
/// trend, was trusted with DY0 3.3 total σ off.
#[derive(Clone, Debug, Default)]
pub(crate) struct AtTheStart {
    /// The misstatements, their gains over the starting fit's set-up and shifts about `about`.
    pub misstated: Vec<Alternative>,
    /// The starting fit's parameters (name, value) the shifts are taken about.
    pub about: Vec<(&'static str, f64)>,
}

impl Assessment {
    /// Weighs each misstatement `start` holds against the final model as a rival of the ladder's
    /// additions (`added`, with evidence gain `ladder_gain` over the starting model): its gain on
    /// the final model's scale is its own less the ladder's; its shift takes each coefficient from
    /// the final estimate to the starting fit's under the misstatement (an added effect's
    /// parameters have no counterpart there and are not moved). Then averaged and judged with the
    /// other alternatives: one scale, one verdict.
    ///
    /// The catch-alls a rung preferred less than the data did (`overruled`) are weighed the same
    /// way: each in place of the law chosen there and what followed, its shift taken from its
    /// refit's drift coefficients.
    pub(crate) fn weigh_instead_of_the_ladder(
        &mut self,
        start: &AtTheStart,
        (added, ladder_gain): (&[String], f64),
        overruled: &[crate::diagnose::ladder::Overruled],
    ) {
        let misstated = if added.is_empty() {
            &[][..]
        } else {
            &start.misstated[..]
        };
        if misstated.is_empty() && overruled.is_empty() {
            return;
        }
        let value = &self.id.best().value;
        let n = self.id.params.len();
        for o in overruled {
            let (mut shift, sigma) = (vec![0.0; n], vec![0.0; n]);
            for (i, p) in self.id.params.iter().enumerate() {
                if let Some((_, v, _)) = o.drift.iter().find(|(name, _, _)| *name == p.name) {
                    shift[i] = v - value[i];
                }
            }
            let mut a = Alternative::new(o.effect.clone(), o.evidence_gain, shift, sigma, None);
            a.instead_of = Some(o.instead_of.join(" + "));
            self.alternatives.push(a);
        }
        for m in misstated {
            let (mut shift, mut sigma) = (vec![0.0; n], vec![0.0; n]);
            for (i, p) in self.id.params.iter().enumerate() {
                if let Some(j) = start.about.iter().position(|(name, _)| *name == p.name) {
                    shift[i] = start.about[j].1 + m.shift[j] - value[i];
                    sigma[i] = m.move_sigma[j];
                }
            }
            let mut a = Alternative::new(
                m.effect.clone(),
                m.evidence_gain - ladder_gain,
                shift,
                sigma,
                m.misstated,
            );
            a.instead_of = Some(added.join(" + "));
            self.alternatives.push(a);
        }
        alternatives::weight(&mut self.alternatives);
        self.unc
            .add_model_spread(&alternatives::averaging_spread(&self.alternatives, n));
        self.reasons = self.reasons_on(&Scale {
            weight: None,
            total_sigma: &self.unc.total_sigma,
        });
    }
}

/// The final fit's parameters minus `from`'s (the same model; state order after the angles).
fn offset(from: &Identification, to: &Identification) -> Vec<f64> {
    from.best()
        .value
        .iter()
        .zip(to.best().value.iter())
        .map(|(a, b)| a - b)
        .collect()
}

/// `a` with its shift taken about the final fit instead of the fit `offset` was taken from.
fn rebased(mut a: Alternative, offset: &[f64]) -> Alternative {
    for (s, o) in a.shift.iter_mut().zip(offset) {
        *s += o;
    }
    a
}

/// When the data moved the set-up within its priors (evidence gain `moved` over the stated
/// set-up's own fit), the catalog effects fitted at the set-up as stated are rivals of that move:
/// a drift trend or a clock running fast can look like a latitude a few hundredths of a degree
/// off. Each is put on the final fit's scale (gain minus `moved`; shift about the final fit).
fn rivals_of_the_move(
    catalog: &Catalog,
    effects: &[&dyn Effect],
    stated: &(Prepared, Identification),
    dcfg: &DiagnoseConfig,
    moved: f64,
    to_final: &[f64],
) -> anyhow::Result<Vec<Alternative>> {
    let at_stated = alternatives::weigh(&stated.0, catalog, effects, dcfg, &stated.1)?;
    Ok(at_stated
        .into_iter()
        .map(|mut a| {
            a.evidence_gain -= moved;
            a.instead_of_setup = true;
            rebased(a, to_final)
        })
        .collect())
}

/// Where the data contradict the stated set-up, a misstated knob's gain is taken over the stated
/// set-up's own fit with the other knobs moving within their priors, while the catalog's effects
/// were weighed on that fit with every knob as stated: a drift trend with a gravity 10 ppm off
/// (a third of its prior) lost to a clock "1043 ppm fast" that took the gravity's move along
/// (2300 against 250), was repaired, and DY0 ended 8.7σ off, trusted. The catalog's effects are
/// ranked again with the set-up where its priors put it (`within`: that move and its gain over
/// the stated fit), and the [`RIVALS_WITH_SET_UP`] best are refitted with the set-up
/// marginalised along (their own knobs' posterior: at the priors' point the latitude, bent by
/// the trend to its bound, stayed there): gains on the stated fit's scale, rivals a
/// misstatement must beat.
pub(crate) fn rivals_within_priors(
    catalog: &Catalog,
    effects: &[&dyn Effect],
    stated: &(Prepared, Identification),
    dcfg: &DiagnoseConfig,
    within: ([f64; 3], f64),
) -> anyhow::Result<Vec<(String, f64)>> {
    let (delta, gain) = within;
    let cfg = &dcfg.identify;
    let prep = crate::identify::setup::moved(&stated.0, delta);
    let model = build_model(prep.site, effects, cfg)?;
    let Ok(id) = identify_from(&model, &prep, cfg, &stated.1) else {
        return Ok(vec![]);
    };
    let mut ranked: Vec<Alternative> = alternatives::weigh(&prep, catalog, effects, dcfg, &id)?
        .into_iter()
        .filter(|a| a.misstated.is_none())
        .collect();
    ranked.sort_by(|a, b| b.evidence_gain.total_cmp(&a.evidence_gain));
    let f0 = crate::identify::neg2_log_evidence(&stated.1.innovations);
    let leaders = &ranked[..ranked.len().min(RIVALS_WITH_SET_UP)];
    // The leaders' and the best pair's refits are independent: on all cores at once (each is
    // a fit and the set-up's refits, mostly one pass after another).
    let (marginalised, pair) = rayon::join(
        || {
            leaders
                .par_iter()
                .map(|a| {
                    let Some(effect) = catalog.by_name(&a.effect) else {
                        return Ok(None);
                    };
                    let mut with: Vec<&dyn Effect> = effects.to_vec();
                    with.push(effect);
                    with_set_up_marginalised(&with, stated, cfg)
                })
                .collect::<anyhow::Result<Vec<Option<f64>>>>()
        },
        || match ranked.first() {
            Some(first) => best_pair(catalog, effects, (&prep, &id), stated, dcfg, &first.effect),
            None => Ok(None),
        },
    );
    let mut out = vec![];
    for (a, g) in leaders.iter().zip(marginalised?) {
        let name = format!("`{}` with the set-up within its priors", a.effect);
        out.push((name.clone(), a.evidence_gain + gain));
        if let Some(g) = g {
            // Beaten by [`CONFOUNDED_MARGIN`], not the plausible margin: a misstated knob and an
            // effect with the set-up moved along can differ by many σ in the coefficients (the
            // clock at 1043 ppm beat the trend by 9 and left DY0 8.7σ off), and which holds is
            // then not settled — as between two effects in the ladder.
            out.push((name, f0 - g + CONFOUNDED_MARGIN - PLAUSIBLE_MARGIN));
        }
    }
    if let Some((name, g)) = pair? {
        out.push((name, f0 - g + CONFOUNDED_MARGIN - PLAUSIBLE_MARGIN));
    }
    Ok(out)
}

/// The best pair with the set-up marginalised: `first` (the best single rival) and the effect
/// that explains most next to it, on its fit with the set-up where its priors put it (`prep`) —
/// one rung of the ladder. A misstatement must beat the combination too: a turn-on transient
/// with set-up errors (24 h at 30 s) was repaired as a clock 4367 ppm fast (gain 1616, against
/// 1590 for the best single rival) although acc-bias and a trend together explained more, and
/// the run was trusted with DZ0 5.1σ off. `moved`: the model's own fit at `prep`, where the
/// fit with `first` starts ([`crate::identify::identify_widened`]). Its name and −2 ln Z; `None`
/// where a fit fails.
fn best_pair(
    catalog: &Catalog,
    effects: &[&dyn Effect],
    (prep, moved): (&Prepared, &Identification),
    stated: &(Prepared, Identification),
    dcfg: &DiagnoseConfig,
    first: &str,
) -> anyhow::Result<Option<(String, f64)>> {
    let cfg = &dcfg.identify;
    let Some(first) = catalog.by_name(first) else {
        return Ok(None);
    };
    let mut with: Vec<&dyn Effect> = effects.to_vec();
    with.push(first);
    let model = build_model(prep.site, &with, cfg)?;
    let Ok(id) = crate::identify::identify_widened(&model, prep, cfg, moved) else {
        return Ok(None);
    };
    let next = alternatives::weigh(prep, catalog, &with, dcfg, &id)?
        .into_iter()
        .filter(|a| a.misstated.is_none())
        .max_by(|a, b| a.evidence_gain.total_cmp(&b.evidence_gain));
    let Some(second) = next.as_ref().and_then(|a| catalog.by_name(&a.effect)) else {
        return Ok(None);
    };
    with.push(second);
    let name = format!(
        "`{}` + `{}` with the set-up within its priors",
        first.name(),
        second.name()
    );
    Ok(with_set_up_marginalised(&with, stated, cfg)?.map(|g| (name, g)))
}

/// Catalog effects refitted with the set-up marginalised in [`rivals_within_priors`].
const RIVALS_WITH_SET_UP: usize = 2;

/// −2 ln Z of the model of `effects` with the set-up within its priors (its fit at the stated
/// set-up, warm-started from the stated fit of the effects it adds to, the knobs weighed about
/// it); `None` where the fit or the knobs fail.
fn with_set_up_marginalised(
    effects: &[&dyn Effect],
    (prep, nested): &(Prepared, Identification),
    cfg: &Config,
) -> anyhow::Result<Option<f64>> {
    let model = build_model(prep.site, effects, cfg)?;
    let Ok(id) = crate::identify::identify_widened(&model, prep, cfg, nested) else {
        return Ok(None);
    };
    // The knobs' model alone: the other set-up terms do not enter the move within the priors.
    let Ok(Some(knobs)) = crate::identify::setup::knob_model(effects, prep, cfg, &id) else {
        return Ok(None);
    };
    let (_, g) = misstated::within_priors(effects, prep, cfg, &id, (&knobs.0, knobs.1))?;
    Ok(Some(
        crate::identify::neg2_log_evidence(&id.innovations) - g,
    ))
}

/// When the data moved the set-up within its priors (evidence gain `moved`, at least
/// [`MIN_EVIDENCE_GAIN`]), a knob misstated
/// whose prior is only the tool's assumption ([`SetupPriors::assumed`]) and that the data alone do
/// not rule out (its gain without the prior odds within [`PLAUSIBLE_MARGIN`]) is the same data
/// told another way: a clock running fast looks like a latitude a few hundredths of a degree off.
/// Only the assumption tells them apart; where they differ beyond the total 1σ the result rests
/// on it, and the user is asked to state what they know.
fn move_confounded(
    alts: &[Alternative],
    moved: f64,
    id: &Identification,
    priors: &SetupPriors,
    scale: &Scale<'_>,
) -> Vec<String> {
    let mut out = vec![];
    if moved < MIN_EVIDENCE_GAIN {
        // The data barely prefer the move (a clean run's noise moves the set-up this much): the
        // stated set-up stands, and every run rests on its priors that much (1 of 100 clean
        // 24-h runs was distrusted for a latitude the data place at ±0.06° about the stated
        // one, gain 2.8; a clock 300 ppm fast moves it with gains 67–85).
        return out;
    }
    for a in alts {
        let Some(m) = &a.misstated else { continue };
        let on_the_data = a.evidence_gain + misstated::PRIOR_ODDS;
        if !priors.assumed[m.index] || on_the_data < -PLAUSIBLE_MARGIN {
            continue;
        }
        let Some((k, z)) = scale.worst(&a.shift).filter(|(_, z)| z.abs() > 1.0) else {
            continue;
        };
        let option = [
            "--latitude-sigma-deg",
            "--clock-sigma-ppm",
            "--gravity-sigma-ppm",
        ];
        out.push(format!(
            "the data moved the set-up within its priors (evidence gain {moved:.1}), and a misstated {} ({} {} where {} is stated) explains them as well on the data alone (gain {on_the_data:.1} before the prior odds) and would move {} by {z:+.1}σ: the result rests on the assumed {} prior — state what you know of the set-up ({}, {}; more digits of the latitude) and rerun",
            m.knob,
            crate::format::pm(m.value, m.sigma),
            m.unit,
            crate::format::sig(m.stated, 9),
            id.params[k].name,
            m.knob,
            option[m.index],
            option.iter().enumerate().filter(|(i, _)| *i != m.index).map(|(_, o)| *o).collect::<Vec<_>>().join(", "),
        ));
    }
    out
}

/// "a longer run (a day at least), " for a run shorter than a day; "a longer run, " otherwise (a
/// 60-h run told to last a day was the generic phrase, and so was a 24-h run).
fn longer(id: &Identification) -> &'static str {
    let hours = id.innovations.last().map_or(0.0, |r| r.t_s) / estimator_core::units::S_PER_H;
    if hours < 23.5 {
        "a longer run (a day at least), "
    } else {
        "a longer run, "
    }
}

/// Whether `a` is a catalog effect the total 1σ already carries as a set-up parameter sized by
/// the data: `drift-daily` or `drift-trend`, when that slow drift is marginalised
/// ([`crate::identify::slow_drift`], its prior's size chosen by evidence up to 58× the prior, past
/// the catalog's). A run that cannot rule such an effect out is not distrusted for it — its spread
/// is in the total already; one whose data prefer it still is, and so is one whose data sized the
/// set-up drift above its prior: they see a drift, and the twin's move is then weighed like any
/// alternative's (a 12-h sine of 7e-4 deg/h, 24 h at 10 s, sized the daily drift to 17× its
/// prior, twin gain 8.9, and was trusted with four coefficients 3.0–3.8 total σ off). (On clean 24-h runs, where one
/// daily cycle, or a trend, is confounded with the constant drifts, the catalog twin stayed within
/// the plausible margin and made 3 of 8 runs — for the trend 4 of 100 — exit 3.)
fn carried_as_setup(a: &Alternative, unc: &Uncertainty) -> bool {
    a.misstated.is_none()
        && SlowDrift::ALL.iter().any(|kind| {
            a.effect == kind.catalog_name()
                && unc.contributions.iter().any(|c| {
                    c.source == kind.source() && !c.sized_by_data && c.cov.iter().any(|v| *v != 0.0)
                })
        })
}

/// Why the alternatives make the result untrusted: one the data prefer, or a plausible one that
/// moves a coefficient beyond its total 1σ.
pub(crate) fn alternatives_untrusted(
    alts: &[Alternative],
    unc: &Uncertainty,
    id: &Identification,
    scale: &Scale<'_>,
) -> Vec<String> {
    let best = alts.iter().map(|a| a.evidence_gain).fold(0.0, f64::max);
    let mut out = vec![];
    for a in alts.iter().filter(|a| a.plausible(best)) {
        let Some((k, z)) = scale.worst(&a.shift) else {
            continue;
        };
        let what = match &a.misstated {
            Some(m) => {
                let stated = format!(
                    "a misstated {} ({} {} where {} is stated)",
                    m.knob,
                    crate::format::pm(m.value, m.sigma),
                    m.unit,
                    crate::format::sig(m.stated, 9)
                );
                match &a.instead_of {
                    Some(added) => format!("{stated} instead of `{added}`"),
                    None => stated,
                }
            }
            None if a.instead_of.is_some() => format!(
                "`{}` instead of `{}`",
                a.effect,
                a.instead_of.as_deref().unwrap_or_default()
            ),
            None if a.instead_of_setup => format!(
                "adding `{}` with the set-up as stated (instead of the set-up the data moved within its priors)",
                a.effect
            ),
            None => format!("adding `{}`", a.effect),
        };
        if a.evidence_gain > MIN_EVIDENCE_GAIN {
            // After the ladder (a misstatement instead of what it added) diagnose has run.
            let next = match (&a.instead_of, &a.misstated) {
                (Some(_), Some(m)) => format!(
                    "{}a second run from another orientation (`driftid plan`) or the {} known better would tell them apart",
                    longer(id),
                    m.knob
                ),
                (Some(added), None) => format!(
                    "{}a second run from another orientation (`driftid plan`) or a bench value of `{added}` would tell them apart",
                    longer(id),
                ),
                _ => "run `driftid diagnose`".into(),
            };
            out.push(format!(
                "the data prefer {what} (evidence gain {:.1}, −2 ln units); with it {} would move by {:+.1}σ — {next}",
                a.evidence_gain, id.params[k].name, z
            ));
        } else if z.abs() > 1.0 && !carried_as_setup(a, unc) {
            let how = if a.evidence_gain > 0.0 {
                format!("better, short of the {MIN_EVIDENCE_GAIN} that would settle it")
            } else {
                format!("almost as well, within {PLAUSIBLE_MARGIN} of the best")
            };
            let settle = match &a.misstated {
                Some(m) => format!("the {} known better", m.knob),
                None => format!("a bench value of `{}`", a.effect),
            };
            out.push(format!(
                "{what} explains the data {how} (evidence gain {:.1}) and would move {} by {:+.1}σ: this run cannot tell them apart — {}a second run from another orientation (`driftid plan`) or {settle} would",
                a.evidence_gain, id.params[k].name, z, longer(id)
            ));
        }
    }
    out
}

/// `identify`'s drift step on a misfit at the settled set-up of `assessed`: profiled on the fit
/// the alternatives were weighed against, so its evidence is on their scale (`None` when the
/// fit is consistent, or no step was found). [`repaired_if_it_wins`] then judges it.
pub(crate) fn drift_step_on_a_misfit(
    effects: &[&dyn Effect],
    cfg: &Config,
    assessed: &Assessment,
    progress: &crate::steps::Progress,
) -> Option<DriftStepFit> {
    let misfit = crate::consistency::consistency_of(&assessed.id, &assessed.prep)
        .is_some_and(|c| !c.is_consistent());
    if !misfit {
        return None;
    }
    progress.note(|| "profiling a gyro drift step".into());
    drift_step::profile(&assessed.prep, effects, cfg, &assessed.id)
}

/// `identify`'s answer to a misfit at the settled set-up of `assessed`: its drift step
/// ([`drift_step_on_a_misfit`]), when it beats every alternative and a warm-up transient (which
/// a step also follows) by the plausible margin, is repaired — modelled from its time on, the
/// model refitted at the `stated` set-up and assessed again (the set-up settles with the step in
/// the model: settled first, the latitude had bent to absorb the step). Returns the effects and
/// assessment to report, the step when it is only named (it explains the misfit but is not
/// repaired: no rival beats it), and whether it was repaired.
pub(crate) fn repaired_if_it_wins<'c>(
    catalog: &'c crate::catalog::Catalog,
    stated: Prepared,
    effects: Vec<&'c dyn Effect>,
    cfg: &Config,
    (assessed, step): (Assessment, Option<DriftStepFit>),
    progress: &crate::steps::Progress,
) -> anyhow::Result<StepJudged<'c>> {
    let judged = |effects, assessed, step, repaired| StepJudged {
        effects,
        assessed,
        step,
        repaired,
    };
    let Some(step) = step else {
        return Ok(judged(effects, assessed, None, false));
    };
    if !step.beats(&assessed.alternatives) {
        return Ok(judged(effects, assessed, Some(step), false));
    }
    let warmup = crate::diagnose::warmup::profile(&assessed.prep, &effects, cfg, &assessed.id);
    if warmup.is_some_and(|w| w.evidence_gain + PLAUSIBLE_MARGIN >= step.evidence_gain) {
        // The warm-up explains it as well or better: the misfit stands; `diagnose` weighs both.
        return Ok(judged(effects, assessed, None, false));
    }
    let (with_step, id) = drift_step::repair(catalog, &stated, &effects, cfg, &step)?;
    let mut prep = stated;
    prep.findings.push(step.repaired());
    let a = assess_with(catalog, &with_step, prep, cfg, id, None, progress)?;
    Ok(judged(with_step, a, None, true))
}

/// What `identify` reports after its drift step is judged ([`repaired_if_it_wins`]).
pub(crate) struct StepJudged<'c> {
    /// The model's effects (with the step, if repaired).
    pub effects: Vec<&'c dyn Effect>,
    /// The assessment to report.
    pub assessed: Assessment,
    /// The step when it is only named.
    pub step: Option<DriftStepFit>,
    /// Whether the step was repaired.
    pub repaired: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalog::paper;

    /// Where a misstated set-up is to be repaired, the stated set-up's assessment handed back
    /// beside the repair is whole — a 1σ per coefficient, its alternatives and reasons — and,
    /// where the model cannot be fitted at the repair, is what stands, not trusted, with the
    /// misstatement named. Before, its 1σ was empty and `identify` panicked printing it (seen
    /// by failing the refit on purpose on a 60-h run with the latitude 0.5° off). The case: 60 h
    /// at 10 s, the metadata latitude 0.5° off (repaired; a day at 30 s leaves it a rival).
    #[test]
    fn the_stated_assessment_beside_a_repair_is_whole() {
        let mut sc = crate::simulate::Scenario::paper();
        (sc.hours, sc.rate_s) = (60.0, 10.0);
        sc.setup_errors.latitude_deg = 0.5;
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let effects = [paper()];
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = crate::identify::identify(&model, &prep, &cfg).unwrap();
        let (first, repair) = assess_as_stated(
            Catalog::builtin(),
            &effects,
            (prep, id),
            &cfg,
            (true, None),
            &Progress::default(),
        )
        .unwrap();
        let (repaired, _, _) = repair.expect("a latitude 0.5° off is repaired");
        let n = first.id.params.len();
        assert_eq!(first.unc.total_sigma.len(), n, "a 1σ per parameter");
        assert!(first
            .unc
            .total_sigma
            .iter()
            .all(|s| s.is_finite() && *s > 0.0));
        assert!(!first.alternatives.is_empty(), "the alternatives weighed");
        let stood = unrepaired(first, &repaired, &anyhow::anyhow!("not positive definite"));
        let said = stood.reasons.join("\n");
        assert!(
            said.contains("the data put the set-up elsewhere (latitude 38.6")
                && said.contains("the estimate is the stated set-up's"),
            "{said}"
        );
    }
}
