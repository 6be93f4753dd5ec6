//! A misstated set-up as an explanation of the data, weighed on the catalog's evidence scale.
//!
//! The set-up's priors ([`crate::identify::setup`]) say how far a *correctly* stated latitude, clock rate or
//! gravity may be off. A *misstated* one — a latitude of another site, a recorder clock or sample
//! interval set wrong, a gravity value of another place — is another hypothesis: that knob with
//! the broad prior [`BROAD`], the others with their priors. On the data's quadratic model of the
//! knobs about the stated set-up ([`KnobModel`]: `f(u) = f0 + gᵀu + ½uᵀHu` in units `u = δ/h`, h
//! each knob's prior 1σ), with prior covariance Λ (identity; knob k's entry `(broad/h)²` when it
//! is misstated), the Laplace evidence is
//!
//! ```text
//! u*(Λ) = −(H + 2Λ⁻¹)⁻¹ g                                     (the knobs' estimate)
//! −2 ln Z(Λ) = f(u*) + u*ᵀΛ⁻¹u* + ln det(1 + Λ^½ H Λ^½ / 2)
//! evidence gain G_k = −2 ln Z(I) − (−2 ln Z(Λ_k)) − 2 ln 100
//! ```
//!
//! against the stated set-up *with its priors* — the fit [`crate::identify::setup::settle`] ends at, the
//! one the catalog's alternatives are weighed against. `f(u*)` comes from refits (a clock 1000 ppm
//! off is 50 prior σ from where the quadratic model was measured); the `ln det` term is the Occam
//! factor of a broad prior the data then narrow; `2 ln 100` ([`PRIOR_ODDS`]) the prior odds of a
//! stated set-up over a misstated one.
//!
//! Where the model holds a tuned `drift-markov`, each misstated knob is refitted with the
//! wander's σ and τ tuned again at its set-up, credited with what that gains beyond tuning
//! again at the stated set-up ([`crate::identify::markov::retune_gain`]): a wander tuned at a
//! misstated latitude stretches to absorb it.
//!
//! A misstatement is *repaired* ([`to_repair`]) only when it beats every other explanation by
//! [`PLAUSIBLE_MARGIN`] and the stated set-up by [`MIN_EVIDENCE_GAIN`]: the knob is then moved to
//! the data's value with the data's 1σ as its prior, and the repair is named. Short of that it is
//! one more alternative, averaged and reported like the catalog's.

use estimator_core::effects::Effect;
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use crate::diagnose::alternatives::{Alternative, Misstated, PLAUSIBLE_MARGIN};
use crate::diagnose::select::MIN_EVIDENCE_GAIN;
use crate::identify::setup::{moved, refit, KnobModel, Uncertainty};
use crate::identify::{Config, Identification, Prepared};
use crate::quality::{Action, Finding};

/// The broad 1σ of a misstated knob: latitude 0.5° (a site's latitude mistaken within a region:
/// beyond it the profile of [`crate::diagnose::latitude`] searches ±12°), clock rate 1000 ppm (a
/// sample interval or clock set wrong by 0.1 %: a quartz crystal is good to 20 ppm, so 1000 is a
/// fault, not a tolerance), gravity 1000 ppm (a gravity value of another place or formula: normal
/// gravity differs by 0.5 % from equator to pole).
pub(crate) const BROAD: [f64; 3] = [0.5, 1000.0, 1000.0];

/// Prior odds against a misstated set-up, −2 ln units: a stated set-up is taken as 100 times
/// likelier than a misstated one before the data are seen (a gross metadata fault in about one
/// recording in a hundred). Without them a clean run's 2.5σ clock estimate would make a
/// misstated clock a plausible rival, and on a day's run (where the data know the clock only to
/// ~600 ppm) one in six clean runs would be distrusted for it (measured with 20:1: 7 of 40).
pub(crate) const PRIOR_ODDS: f64 = 9.210_340_371_976_184; // 2 ln 100

/// The knobs' names and units, in the [`KnobModel`]'s order.
pub(crate) const KNOBS: [(&str, &str); 3] = [
    ("latitude", "deg"),
    ("clock rate", "ppm"),
    ("gravity", "ppm"),
];

/// The misstatements weighed ([`weigh`]).
#[derive(Clone)]
pub(crate) struct Weighed {
    /// Each knob misstated, its evidence gain over the stated set-up with its priors (or over
    /// the stated set-up's own fit when the data contradict those priors).
    pub alternatives: Vec<Alternative>,
    /// The evidence gain of the stated set-up with its priors over its own fit (−2 ln units;
    /// `None` when the data contradict those priors): add it to put the alternatives on the
    /// scale of effects refitted at the stated set-up.
    pub stated_gain: Option<f64>,
    /// The set-up moved within its priors (the first hypothesis' mode: latitude deg, clock ppm,
    /// gravity ppm) and that hypothesis' evidence gain over the stated set-up's own fit, also
    /// where the data contradict the priors (`None` for a single pass): where a misstatement's
    /// gain is taken over the stated fit, the other knobs move within their priors with it, and
    /// a catalog effect is its rival only with them moved too ([`crate::assess`]).
    pub within_priors: Option<([f64; 3], f64)>,
    /// The parameters the alternatives' shifts are taken about (the refit at the priors'
    /// hypothesis; empty for a single pass).
    pub about: Vec<f64>,
}

impl Weighed {
    /// Nothing weighed (a single pass).
    pub(crate) fn none() -> Self {
        Weighed {
            alternatives: vec![],
            stated_gain: None,
            within_priors: None,
            about: vec![],
        }
    }

    /// The alternatives with gains over the stated set-up's own fit, and the stated set-up with
    /// its priors as one more rival (what the catalog's refits at the stated set-up compare to).
    pub(crate) fn on_the_stated_fit(mut self) -> (Vec<Alternative>, Option<(String, f64)>) {
        let g0 = self.stated_gain.unwrap_or(0.0);
        for a in &mut self.alternatives {
            a.evidence_gain += g0;
        }
        let rival = self
            .stated_gain
            .map(|g| ("the stated set-up within its priors".to_string(), g));
        (self.alternatives, rival)
    }
}

/// Each knob misstated, as an alternative explanation of the fit `id` of `effects` on `prep` (the
/// stated set-up, the one `unc` was computed about). Empty for a single pass.
///
/// `keep`: where to keep them (with the uncertainty `unc` about the same fit) for a later
/// assessment of the same fit ([`crate::assess`]), with the model refitted where
/// [`crate::identify::setup::settle`] would settle: that refit is then made beside the
/// misstatements' where it is the stated set-up with its priors, and serves as that
/// hypothesis' refit ([`Refitted::weigh`]).
pub(crate) fn weigh(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    (id, unc): (&Identification, &Uncertainty),
    keep: Option<&mut crate::identify::setup::Computed>,
) -> anyhow::Result<Weighed> {
    use crate::identify::setup::{as_refit, settling_fit, settling_refit};
    let at = keep
        .is_some()
        .then(|| settling_refit(unc))
        .flatten()
        .filter(|d| Some(*d) == priors_refit_at(unc));
    let (settling, refitted) = rayon::join(
        || at.map(|d| settling_fit(effects, prep, cfg, id, d)),
        || refits(effects, prep, cfg, id, unc, at.is_some()),
    );
    let settling = settling.and_then(Result::ok);
    let weighed = match refitted? {
        Some(r) => r.weigh(
            effects,
            prep,
            cfg,
            (id, unc),
            settling.as_ref().and_then(as_refit),
        )?,
        None => Weighed::none(),
    };
    if let Some(k) = keep {
        if let Some(fit) = settling {
            k.keep_settling(fit);
        }
        k.keep_misstated(weighed.clone());
    }
    Ok(weighed)
}

/// Where the stated set-up with its priors is refitted (the first hypothesis' mode: latitude
/// deg, clock ppm, gravity ppm); `None` for a single pass. Where it is where
/// [`crate::identify::setup::settle`] refits, that refit serves both
/// ([`Refitted::weigh`]).
pub(crate) fn priors_refit_at(unc: &Uncertainty) -> Option<[f64; 3]> {
    let km = unc.knobs.as_ref()?;
    Some(hypotheses(km, &[], latitude_bound(unc))[0].delta(km))
}

/// A hypothesis' refit: −2 ln p(y) and the parameters after the angles
/// ([`crate::identify::setup::refit`]).
type Fit = (f64, DVector<f64>);

/// The misstatements' refits ([`refits`]): what [`Refitted::weigh`] weighs them with.
pub(crate) struct Refitted {
    /// The live knobs, in the order of the hypotheses after the first.
    live: Vec<usize>,
    /// The hypotheses: the priors as stated, then each live knob broad.
    laplace: Vec<Laplace>,
    /// Their refits (−2 ln p(y), the parameters), the first missing where it is awaited.
    fits: Vec<Option<Fit>>,
}

/// The refits of each hypothesis of [`weigh`] about the fit `id` (`None` for a single pass),
/// all but the priors' own when `priors_elsewhere` (it is [`crate::identify::setup::settle`]'s:
/// [`priors_refit_at`]), on every core.
pub(crate) fn refits(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
    unc: &Uncertainty,
    priors_elsewhere: bool,
) -> anyhow::Result<Option<Refitted>> {
    let Some(km) = &unc.knobs else {
        return Ok(None);
    };
    let live = live_knobs(prep, km);
    let laplace = hypotheses(km, &live, latitude_bound(unc));
    let skip = usize::from(priors_elsewhere);
    // Beside them, what tuning the wander again gains at the stated set-up itself: each
    // misstatement is credited only with what it gains beyond that.
    let (reference, fits) = rayon::join(
        || crate::identify::markov::retune_gain(prep, effects, cfg, id).map(|g| g.0),
        || -> Vec<anyhow::Result<(Fit, Option<Fit>)>> {
            (skip..laplace.len())
                .into_par_iter()
                .map(|j| {
                    let at = moved(prep, laplace[j].delta(km));
                    // The stated set-up within its priors keeps the wander as tuned: its
                    // set-up moves within the priors alone.
                    let held = refit(&at, effects, cfg, id)?;
                    Ok((
                        held,
                        (j > 0).then(|| retuned(&at, effects, cfg, id)).flatten(),
                    ))
                })
                .collect()
        },
    );
    let mut out: Vec<Option<Fit>> = vec![None; skip];
    for f in fits {
        let (held, retuned) = f?;
        let bias = reference.unwrap_or(0.0);
        out.push(Some(match retuned {
            Some((f, c)) if f + bias < held.0 => (f + bias, c),
            _ => held,
        }));
    }
    Ok(Some(Refitted {
        live,
        laplace,
        fits: out,
    }))
}

/// A misstated knob's refit at `at` with the wander tuned again there, where the model holds a
/// tuned `drift-markov` and that gains ([`crate::identify::markov::retune_gain`]); `None`
/// otherwise, or where the refit fails (the wander held then stands).
fn retuned(
    at: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
) -> Option<Fit> {
    use crate::identify::markov::{refit_with, retune_gain};
    let (gain, gm) = retune_gain(at, effects, cfg, id)?;
    (gain > 0.0)
        .then(|| refit_with(at, effects, cfg, id, &gm).ok())
        .flatten()
}

impl Refitted {
    /// The knobs misstated, weighed on their refits; `at_priors`: the priors' refit where
    /// [`refits`] left it to another (refitted here where that other is `None`: it failed).
    pub(crate) fn weigh(
        self,
        effects: &[&dyn Effect],
        prep: &Prepared,
        cfg: &Config,
        (id, unc): (&Identification, &Uncertainty),
        at_priors: Option<Fit>,
    ) -> anyhow::Result<Weighed> {
        let Some(km) = &unc.knobs else {
            // `refits` returns no `Refitted` without knobs.
            return Ok(Weighed::none());
        };
        let Refitted {
            live,
            laplace,
            mut fits,
        } = self;
        if fits[0].is_none() {
            fits[0] = Some(match at_priors {
                Some(f) => f,
                None => refit(&moved(prep, laplace[0].delta(km)), effects, cfg, id)?,
            });
        }
        let fits: Vec<Fit> = fits.into_iter().flatten().collect();
        weigh_fitted(km, (&live, &laplace, &fits), effects, prep, cfg, unc)
    }
}

/// [`weigh`]'s judgement of the refits `fits` of the hypotheses `laplace` (the priors as
/// stated, then each of the `live` knobs broad).
fn weigh_fitted(
    km: &KnobModel,
    (live, laplace, fits): (&[usize], &[Laplace], &[Fit]),
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    unc: &Uncertainty,
) -> anyhow::Result<Weighed> {
    // Against the stated set-up with its priors — unless the data contradict those (the
    // χ² check or the latitude's digits): then that hypothesis is out, and the stated set-up's
    // own fit is the reference, as it is for the catalog's alternatives weighed on it.
    let contradicted = !unc.untrusted_reasons().is_empty();
    let priors_z = laplace[0].neg2_ln_z(fits[0].0);
    let base = if contradicted { km.f0 } else { priors_z };
    let reference = Reference {
        km,
        laplace: &laplace[0],
        params: &fits[0].1,
        base,
        stated: stated_values(prep),
    };
    let out = live
        .iter()
        .enumerate()
        .map(|(j, &k)| {
            let (l, (f, c)) = (&laplace[j + 1], &fits[j + 1]);
            let a = knob_misstated(&reference, k, l, *f, c);
            if k == 0 {
                latitude_far_off(&reference, l, effects, prep, cfg).unwrap_or(a)
            } else {
                a
            }
        })
        .collect();
    Ok(Weighed {
        alternatives: out,
        stated_gain: (!contradicted).then_some(km.f0 - base),
        within_priors: Some((laplace[0].delta(km), km.f0 - priors_z)),
        about: fits[0].1.iter().copied().collect(),
    })
}
/// [`Weighed::within_priors`] alone: the set-up moved within its priors and that hypothesis'
/// gain, without the misstatements' refits and the far latitude's profile — all a rival weighed
/// with the set-up marginalised needs (`crate::assess`; the far latitude's profile, 21 fits and
/// more, made `identify` of a 60-h run with a latitude 1.6° off take 9 s). `None` for a single
/// pass. `knobs`: the fit's [`KnobModel`] and the latitude's bound
/// ([`crate::identify::setup::knob_model`]).
pub(crate) fn within_priors(
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
    (km, bound): (&KnobModel, Option<f64>),
) -> anyhow::Result<([f64; 3], f64)> {
    let priors = hypotheses(km, &[], bound).remove(0);
    let (f, _) = refit(&moved(prep, priors.delta(km)), effects, cfg, id)?;
    Ok((priors.delta(km), km.f0 - priors.neg2_ln_z(f)))
}

/// The latitude's hard bound (its written digits), where `unc` has one.
fn latitude_bound(unc: &Uncertainty) -> Option<f64> {
    unc.contributions
        .iter()
        .find(|c| c.source == "latitude")
        .and_then(|c| c.bound)
}

/// What each misstated knob is weighed against: the stated set-up with its priors (the first
/// hypothesis, `laplace`), its fit's parameters, its −2 ln Z (`base`) and the stated knob values.
struct Reference<'a> {
    km: &'a KnobModel,
    laplace: &'a Laplace,
    params: &'a DVector<f64>,
    base: f64,
    stated: [f64; 3],
}

/// The knobs that can be misstated here (with a prior). A gravity derived from the stated
/// latitude (normal gravity) that the data find far off says the site is elsewhere (another
/// latitude or altitude), not that a gravity value was mistaken: that is the latitude's profile
/// to name ([`crate::diagnose::latitude`]).
fn live_knobs(prep: &Prepared, km: &KnobModel) -> Vec<usize> {
    let derived = (prep.site.gravity_mps2
        - estimator_core::frames::normal_gravity(prep.site.latitude_rad))
    .abs()
        < 1e-12;
    (0..3)
        .filter(|&k| km.unit[k] > 0.0 && !(k == 2 && derived))
        .collect()
}

/// The hypotheses' Laplace approximations: the priors as stated (first), then each `live` knob
/// broad. The latitude's own prior is uniform within its written digits: the Gaussian stand-in
/// must not let it wander beyond them (a clock 1000 ppm off would hide in a latitude 0.06° off
/// one written "39.1").
fn hypotheses(km: &KnobModel, live: &[usize], bound: Option<f64>) -> Vec<Laplace> {
    let lambdas: Vec<[f64; 3]> = std::iter::once([1.0; 3])
        .chain(live.iter().map(|&k| {
            let mut l = [1.0; 3];
            l[k] = (BROAD[k] / km.unit[k]).powi(2);
            l
        }))
        .collect();
    lambdas
        .iter()
        .map(|l| Laplace::new(km, *l, bound))
        .collect()
}

/// Knob `k` misstated as an alternative: its hypothesis `l` with broad prior, fitted to
/// −2 ln p(y) `f` with parameters `c`, against the `reference`.
fn knob_misstated(
    reference: &Reference,
    k: usize,
    l: &Laplace,
    f: f64,
    c: &DVector<f64>,
) -> Alternative {
    let km = reference.km;
    let (u, var) = (l.u[k], l.var[k]);
    let (name, unit) = KNOBS[k];
    let sens = km.sens.column(k);
    let shift = c - reference.params;
    Alternative::new(
        format!("{name} misstated"),
        reference.base - l.neg2_ln_z(f) - PRIOR_ODDS,
        shift.iter().copied().collect(),
        sens.iter().map(|s| var.sqrt() * s.abs()).collect(),
        Some(Misstated {
            knob: name,
            unit,
            stated: reference.stated[k],
            value: reference.stated[k] + u * km.unit[k],
            sigma: var.sqrt() * km.unit[k],
            index: k,
        }),
    )
}

/// A latitude the broad prior `l` puts beyond 3σ of where its own prior does, weighed by full
/// fits with gravity kept ([`profiled_latitude`]); `None` when it is not that far (or the profile
/// fails). The quadratic model moves normal gravity with the latitude (4.4 ppm per 0.05°, 26σ of
/// what the data know of gravity) and misses far from the stated latitude.
fn latitude_far_off(
    reference: &Reference,
    l: &Laplace,
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
) -> Option<Alternative> {
    let km = reference.km;
    let (u, var) = (l.u[0], l.var[0]);
    let far = ((u - reference.laplace.u[0]) * km.unit[0]).abs() > 3.0 * var.sqrt() * km.unit[0];
    if !far {
        return None;
    }
    let start = reference.stated[0] + u * km.unit[0];
    // The other knobs' share of −2 ln Z under this hypothesis, so that the profiled latitude is
    // weighed on the scale of the others.
    let others = l.ln_det - (1.0 + l.lambda[0] * km.hess[(0, 0)] / 2.0).ln()
        + (1..3).map(|i| l.u[i] * l.u[i] / l.lambda[i]).sum::<f64>();
    profiled_latitude(
        km,
        effects,
        prep,
        cfg,
        (reference.params, reference.base - others),
        reference.stated[0],
        start,
    )
}

/// The knobs' Laplace approximation under prior covariance Λ (diagonal, prior units).
struct Laplace {
    /// Λ's diagonal.
    lambda: [f64; 3],
    /// The knobs' estimate u*.
    u: [f64; 3],
    /// Its variances.
    var: [f64; 3],
    /// `ln det(1 + Λ^½ H Λ^½ / 2)`.
    ln_det: f64,
}

impl Laplace {
    /// `lat_bound`: the latitude's hard half-width (deg) when it has its own prior.
    fn new(km: &KnobModel, lambda: [f64; 3], lat_bound: Option<f64>) -> Self {
        let live = |k: usize| km.unit[k] > 0.0;
        let mut a = km.hess.clone();
        let mut b = km.hess.clone();
        for i in 0..3 {
            a[(i, i)] += if live(i) { 2.0 / lambda[i] } else { 1.0 };
            for j in 0..3 {
                b[(i, j)] *= (lambda[i] * lambda[j]).sqrt() / 2.0;
            }
            b[(i, i)] += 1.0;
        }
        let inv = a
            .clone()
            .try_inverse()
            .unwrap_or_else(|| DMatrix::identity(3, 3));
        let mut u = -(&inv * &km.grad);
        if let Some(b) = lat_bound.filter(|_| lambda[0] == 1.0 && km.unit[0] > 0.0) {
            let cap = b / km.unit[0];
            if u[0].abs() > cap {
                // The latitude at its bound, the other knobs where the data then put them.
                u[0] = cap.copysign(u[0]);
                let rest = a.view((1, 1), (2, 2)).into_owned();
                let rhs = -(km.grad.rows(1, 2) + km.hess.view((1, 0), (2, 1)) * u[0]);
                if let Some(r) = rest.try_inverse() {
                    let ur = r * rhs;
                    u[1] = ur[0];
                    u[2] = ur[1];
                }
            }
        }
        let ln_det = b.determinant().max(1e-300).ln();
        Laplace {
            lambda,
            u: [u[0], u[1], u[2]],
            var: [0, 1, 2].map(|k| 2.0 * inv[(k, k)]),
            ln_det,
        }
    }

    /// The knobs' offsets from the stated set-up, in their units.
    fn delta(&self, km: &KnobModel) -> [f64; 3] {
        [0, 1, 2].map(|k| self.u[k] * km.unit[k])
    }

    /// −2 ln Z with `f` = −2 ln p(y) refitted at u*.
    fn neg2_ln_z(&self, f: f64) -> f64 {
        f + (0..3)
            .map(|k| self.u[k] * self.u[k] / self.lambda[k])
            .sum::<f64>()
            + self.ln_det
    }
}

/// The misstated latitude from full fits (the Earth rate's direction turns with the latitude, so
/// far from the stated one the quadratic model misses, and −2 ln p(y) has local minima): from
/// the quadratic model's estimate `start` (deg) — or, more than 0.1° away, from the best of it
/// and a 0.1° grid over ±2 broad σ — Newton steps with three-point differences 0.01° apart; then the broad prior's penalty and
/// Occam factor with that estimate and its 1σ, against `base` (−2 ln Z of the stated set-up with
/// its priors, its parameters `c0`).
fn profiled_latitude(
    km: &KnobModel,
    effects: &[&dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    (c0, base): (&DVector<f64>, f64),
    stated: f64,
    start: f64,
) -> Option<Alternative> {
    use crate::diagnose::latitude::{screen, Fits, SiteAt};
    const STEP_DEG: f64 = 0.01;
    // Gravity kept as stated: a misstated latitude need not mean a misstated gravity (one measured
    // on site), and where both are wrong the set-up's gravity prior then takes the rest.
    let keep_gravity: SiteAt = |p, l| crate::identify::setup::at_latitude_with(p, l, false);
    let fits = Fits::new(prep, effects, cfg, keep_gravity);
    // Within 0.1° of the stated latitude the quadratic model's estimate is a good start;
    // beyond, the best of a grid ranked by the screen (two EKF passes a latitude where a full fit
    // off the minimum takes the continuation's ~70 ms; it ranks 0.1° cells as the fits do, see
    // the test `the_screen_ranks_a_misstated_latitudes_grid_as_the_fits_do`).
    let mut l = start;
    if (start - stated).abs() > 0.1 {
        let grid: Vec<f64> = (-10..=10)
            .map(|k| stated + 0.1 * k as f64)
            .chain(std::iter::once(start))
            .collect();
        let vals: Vec<f64> = grid
            .par_iter()
            .map(|&l| screen(prep, effects, cfg, keep_gravity, l))
            .collect();
        l = grid[(0..grid.len()).min_by(|&a, &b| vals[a].total_cmp(&vals[b]))?];
    }
    let mut best = None;
    for _ in 0..4 {
        // The centre first: the stencil's fits are warm-started from it.
        let c = fits.fit(l)?;
        let [m, p] = &fits.side_by_side(&[l - STEP_DEG, l + STEP_DEG])[..] else {
            return None;
        };
        let (m, p) = (m.clone()?, p.clone()?);
        let g = (p.evidence - m.evidence) / (2.0 * STEP_DEG);
        let h = (p.evidence - 2.0 * c.evidence + m.evidence) / (STEP_DEG * STEP_DEG);
        if h <= 0.0 {
            return None;
        }
        let dl = (-g / h).clamp(-1.0, 1.0);
        best = Some((c.evidence, (2.0 / h).sqrt(), c));
        if dl.abs() < 0.5 * (2.0 / h).sqrt() {
            break;
        }
        l += dl;
    }
    let (fb, sigma, at) = best?;
    let n = c0.len();
    let shift = DVector::from_fn(n, |i, _| at.id.best().value[i] - c0[i]);
    let lambda = (BROAD[0] / sigma).powi(2);
    let u = (l - stated) / BROAD[0];
    // The other knobs as stated (their priors' share is small beside a latitude this far off).
    let gain = base - (fb + u * u + (1.0 + lambda).ln()) - PRIOR_ODDS;
    let sens = km.sens.column(0) / km.unit[0];
    Some(Alternative::new(
        "latitude misstated".into(),
        gain,
        shift.iter().copied().collect(),
        sens.iter().map(|s| sigma * s.abs()).collect(),
        Some(Misstated {
            knob: KNOBS[0].0,
            unit: KNOBS[0].1,
            stated,
            value: l,
            sigma,
            index: 0,
        }),
    ))
}

/// The stated latitude (deg), clock rate and gravity (ppm of the stated value: 0).
fn stated_values(prep: &Prepared) -> [f64; 3] {
    [
        (prep.site.latitude_rad.to_degrees() * 1e9).round() / 1e9,
        0.0,
        0.0,
    ]
}

/// The misstatement to repair among `alts` (every explanation weighed, the catalog's and the
/// set-up's) and `rivals` (further explanations' gains, e.g. refitted catalog effects): the best
/// of all, ahead of every other by [`PLAUSIBLE_MARGIN`] and of the stated set-up by
/// [`MIN_EVIDENCE_GAIN`].
pub(crate) fn to_repair(alts: &[Alternative], rivals: &[(String, f64)]) -> Option<Misstated> {
    let best = alts
        .iter()
        .max_by(|a, b| a.evidence_gain.total_cmp(&b.evidence_gain))?;
    let m = best.misstated?;
    let next = alts
        .iter()
        .filter(|a| !std::ptr::eq(*a, best))
        .map(|a| a.evidence_gain)
        .chain(rivals.iter().map(|r| r.1))
        .fold(0.0, f64::max);
    (best.evidence_gain > MIN_EVIDENCE_GAIN && best.evidence_gain - next >= PLAUSIBLE_MARGIN)
        .then_some(m)
}

/// When misstatements beat every other explanation by [`PLAUSIBLE_MARGIN`] but not each other
/// (a clock 1000 ppm fast and a latitude 0.07° off fit 60 h alike): the set-up is wrong, which
/// part the run cannot tell. A finding that is not repaired (no physical effect is then added
/// to explain it), naming them and what would tell them apart.
pub(crate) fn confounded(mis: &[Alternative], rivals: &[(String, f64)]) -> Option<Finding> {
    let best = mis
        .iter()
        .map(|a| a.evidence_gain)
        .fold(f64::NEG_INFINITY, f64::max);
    let rival = rivals.iter().map(|r| r.1).fold(0.0, f64::max);
    if !(best > MIN_EVIDENCE_GAIN && best - rival >= PLAUSIBLE_MARGIN) {
        return None;
    }
    let close: Vec<String> = mis
        .iter()
        .filter(|a| a.evidence_gain > best - PLAUSIBLE_MARGIN)
        .filter_map(|a| {
            let m = a.misstated?;
            Some(format!(
                "the {} at {} {} (stated {}; evidence gain {:.1})",
                m.knob,
                crate::format::pm(m.value, m.sigma),
                m.unit,
                crate::format::sig(m.stated, 9),
                a.evidence_gain
            ))
        })
        .collect();
    (close.len() > 1).then(|| Finding {
        kind: crate::quality::Kind::SetUp,
        message: format!(
            "the stated set-up is wrong, but this run cannot tell which part: {} explain the data alike, better than any physical effect (by {:.1} or more); state the others to the precision you know them (a latitude with all its digits, `--latitude-sigma-deg`; a disciplined clock, `--clock-sigma-ppm`) and run again",
            close.join(" or "),
            best - rival
        ),
        start_s: None,
        end_s: None,
        samples: 0,
        action: Action::NotRepaired,
    })
}

/// `prep` and `cfg` with the misstated knob repaired: moved to the data's value, its prior the
/// data's 1σ, and the finding that names it among the measurements' findings (`alts`, `rivals`:
/// what it beat).
pub(crate) fn repair(
    prep: &Prepared,
    cfg: &Config,
    m: &Misstated,
    alts: &[Alternative],
    rivals: &[(String, f64)],
) -> (Prepared, Config) {
    let mut p = if m.index == 0 {
        // As it was weighed: gravity kept ([`profiled_latitude`]).
        crate::identify::setup::at_latitude_with(prep, m.value, false)
    } else {
        let mut d = [0.0; 3];
        d[m.index] = m.value - m.stated;
        moved(prep, d)
    };
    let mut c = cfg.clone();
    match m.index {
        0 => c.setup.latitude_sigma_deg = Some(m.sigma),
        1 => c.setup.clock_sigma_ppm = m.sigma,
        _ => c.setup.gravity_sigma_ppm = m.sigma,
    }
    let this = alts
        .iter()
        .find(|a| a.misstated.is_some_and(|x| x.index == m.index))
        .map(|a| a.evidence_gain);
    let next = alts
        .iter()
        .filter(|a| a.misstated.is_none_or(|x| x.index != m.index))
        .map(|a| (a.effect.as_str(), a.evidence_gain))
        .chain(rivals.iter().map(|r| (r.0.as_str(), r.1)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    p.findings.push(Finding {
        kind: crate::quality::Kind::SetUp,
        message: format!(
            "the {} is misstated: the data put it at {} {} (stated {}); this explains the data better than the stated value (evidence gain {:.1}, −2 ln units) and than every other explanation{} — repaired; correct it in the recording's metadata",
            m.knob,
            crate::format::pm(m.value, m.sigma),
            m.unit,
            crate::format::sig(m.stated, 9),
            this.unwrap_or(f64::NAN),
            next.map(|(e, g)| format!(" (next: `{e}`, {g:.1})"))
                .unwrap_or_default()
        ),
        start_s: None,
        end_s: None,
        samples: 0,
        action: Action::Repaired,
    });
    (p, c)
}
