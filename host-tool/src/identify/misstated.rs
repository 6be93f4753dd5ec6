//! A misstated set-up as an explanation of the data, weighed on the catalog's evidence scale.
//!
//! The set-up's priors ([`super::setup`]) say how far a *correctly* stated latitude, clock rate or
//! gravity may be off. A *misstated* one — a latitude of another site, a recorder clock or sample
//! interval set wrong, a gravity value of another place — is another hypothesis: that knob with
//! the broad prior [`BROAD`], the others as stated. On the data's quadratic model of the knobs
//! about the stated set-up ([`KnobModel`]; units `u = δ/h`, h the knob's prior 1σ) and with
//! `λ = (broad/h)²`:
//!
//! ```text
//! u* = −g_k / (H_kk + 2/λ),   var u* = 2 / (H_kk + 2/λ)          (its estimate)
//! −2 ln Z = f(u*) + u*²/λ + ln(1 + λ H_kk / 2)                     (Laplace)
//! evidence gain G = f(0) − (−2 ln Z) − 2 ln 20
//! ```
//!
//! `f(u*)` and `f(0)` come from refits (the quadratic model is measured at ±1 prior σ and a clock
//! 1000 ppm off is 50 of them), so G is on the scale of the catalog's refits
//! ([`crate::diagnose::select`]): the gain over the model with the set-up as stated. The
//! `ln(1 + λH/2)` term is the Occam factor of a broad prior the data then narrow; `2 ln 20`
//! ([`PRIOR_ODDS`]) the prior odds of a stated set-up over a misstated one.
//!
//! A misstatement is *repaired* ([`to_repair`]) only when it beats every other explanation by
//! [`PLAUSIBLE_MARGIN`] and the stated set-up by [`MIN_EVIDENCE_GAIN`]: the knob is then moved to
//! the data's value with the data's 1σ as its prior, and the repair is named. Short of that it is
//! one more alternative, averaged and reported like the catalog's.

use estimator_core::effects::Effect;
use nalgebra::DVector;
use rayon::prelude::*;

use super::setup::{moved, refit, KnobModel, Uncertainty};
use super::{Config, Identification, Prepared};
use crate::diagnose::alternatives::{Alternative, Misstated, PLAUSIBLE_MARGIN};
use crate::diagnose::select::MIN_EVIDENCE_GAIN;
use crate::quality::{Action, Finding};

/// The broad 1σ of a misstated knob: latitude 0.5° (a site's latitude mistaken within a region:
/// beyond it the profile of [`crate::quality::latitude`] searches ±12°), clock rate 1000 ppm (a
/// sample interval or clock set wrong by 0.1 %: a quartz crystal is good to 20 ppm, so 1000 is a
/// fault, not a tolerance), gravity 1000 ppm (a gravity value of another place or formula: normal
/// gravity differs by 0.5 % from equator to pole).
pub const BROAD: [f64; 3] = [0.5, 1000.0, 1000.0];

/// Prior odds against a misstated set-up, −2 ln units: a stated set-up is taken as 20 times
/// likelier than a misstated one before the data are seen (a gross metadata fault is the
/// exception, not the rule). Without it a clean run's 2.5σ clock estimate (p ≈ 1 %) would make
/// a misstated clock a plausible rival.
pub const PRIOR_ODDS: f64 = 5.991_464_547_107_982; // 2 ln 20

/// The knobs' names and units, in the [`KnobModel`]'s order.
pub const KNOBS: [(&str, &str); 3] = [("latitude", "deg"), ("clock rate", "ppm"), ("gravity", "ppm")];

/// Each knob misstated, as an alternative explanation of the fit `id` of `effects` on `prep` (the
/// stated set-up, the one `unc` was computed about). Empty for a single pass.
pub fn weigh(
    effects: &[&'static dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
    unc: &Uncertainty,
) -> anyhow::Result<Vec<Alternative>> {
    let Some(km) = &unc.knobs else {
        return Ok(vec![]);
    };
    let live: Vec<usize> = (0..3).filter(|&k| km.unit[k] > 0.0).collect();
    let points: Vec<[f64; 3]> = std::iter::once([0.0; 3])
        .chain(live.iter().map(|&k| {
            let mut d = [0.0; 3];
            d[k] = estimate(km, k).0 * km.unit[k];
            d
        }))
        .collect();
    let fits: Vec<anyhow::Result<(f64, DVector<f64>)>> = points
        .par_iter()
        .map(|d| refit(&moved(prep, *d), effects, cfg, id))
        .collect();
    let fits = fits.into_iter().collect::<anyhow::Result<Vec<_>>>()?;
    let (f0, c0) = &fits[0];
    let stated = stated_values(prep);
    let mut out: Vec<Alternative> = live
        .iter()
        .zip(&fits[1..])
        .map(|(&k, (f, c))| alternative(km, k, f0 - f, c - c0, stated[k]))
        .collect();
    // A latitude far from the stated one is beyond the quadratic model's reach (the Earth rate's
    // direction turns with it): its profile over full fits decides.
    if let Some(a) = out.iter_mut().find(|a| {
        a.misstated
            .is_some_and(|m| m.index == 0 && (m.value - m.stated).abs() > LATITUDE_REACH_DEG)
    }) {
        let start = a.misstated.map_or(stated[0], |m| m.value);
        if let Some(p) = profiled_latitude(km, effects, prep, cfg, id, stated[0], start) {
            *a = p;
        }
    }
    Ok(out)
}

/// How far from the stated latitude the quadratic model's estimate is taken, deg (a few of its
/// ±1σ finite-difference steps for a latitude written to 0.1°).
pub const LATITUDE_REACH_DEG: f64 = 0.05;

/// The misstated latitude from full fits (the Earth rate's direction turns with the latitude, so
/// far from the stated one the quadratic model misses, and −2 ln p(y) has local minima): the
/// best of a 0.1° grid over ±2 broad σ and the quadratic model's estimate `start` (deg), then
/// Newton steps with three-point differences 0.01° apart; then the broad prior's penalty and
/// Occam factor with that estimate and its 1σ.
fn profiled_latitude(
    km: &KnobModel,
    effects: &[&'static dyn Effect],
    prep: &Prepared,
    cfg: &Config,
    id: &Identification,
    stated: f64,
    start: f64,
) -> Option<Alternative> {
    const STEP_DEG: f64 = 0.01;
    // Gravity kept as stated: a misstated latitude need not mean a misstated gravity (one measured
    // on site), and where both are wrong the set-up's gravity prior then takes the rest.
    let f = |l: f64| {
        let p = super::setup::at_latitude_with(prep, l, false);
        let model = super::build_model(p.site, effects, cfg).ok()?;
        let id = super::identify(&model, &p, cfg).ok()?;
        Some((crate::diagnose::select::neg2_log_evidence(&id), id))
    };
    let f_stated = crate::diagnose::select::neg2_log_evidence(id);
    let grid: Vec<f64> = (-10..=10)
        .map(|k| stated + 0.1 * k as f64)
        .chain(std::iter::once(start))
        .collect();
    let vals: Vec<f64> = grid
        .par_iter()
        .map(|&l| f(l).map_or(f64::INFINITY, |x| x.0))
        .collect();
    let k = (0..grid.len()).min_by(|&a, &b| vals[a].total_cmp(&vals[b]))?;
    let mut l = grid[k];
    let mut best: Option<(f64, f64, Identification)> = None;
    for _ in 0..6 {
        let ((m, c), p) = rayon::join(
            || rayon::join(|| f(l - STEP_DEG), || f(l)),
            || f(l + STEP_DEG),
        );
        let (m, c, p) = (m?, c?, p?);
        let g = (p.0 - m.0) / (2.0 * STEP_DEG);
        let h = (p.0 - 2.0 * c.0 + m.0) / (STEP_DEG * STEP_DEG);
        if h <= 0.0 {
            return None;
        }
        let dl = (-g / h).clamp(-1.0, 1.0);
        best = Some((c.0, (2.0 / h).sqrt(), c.1));
        if dl.abs() < 0.1 * (2.0 / h).sqrt() {
            break;
        }
        l += dl;
    }
    let (fb, sigma, at) = best?;
    let n = id.params.len();
    let shift = DVector::from_fn(n, |i, _| at.best().value[i] - id.best().value[i]);
    let lambda = (BROAD[0] / sigma).powi(2);
    let u = (l - stated) / BROAD[0];
    let gain = f_stated - fb - u * u - (1.0 + lambda).ln() - PRIOR_ODDS;
    let sens = km.sens.column(0) / km.unit[0];
    Some(Alternative {
        effect: "latitude misstated".into(),
        evidence_gain: gain,
        weight: 0.0,
        reach: (0..n)
            .map(|i| shift[i].abs() + 2.0 * sigma * sens[i].abs())
            .collect(),
        shift: shift.iter().copied().collect(),
        misstated: Some(Misstated {
            knob: KNOBS[0].0,
            unit: KNOBS[0].1,
            stated,
            value: l,
            sigma,
            index: 0,
        }),
    })
}

/// The knob's estimate under its broad prior and that estimate's variance, both in prior units u.
fn estimate(km: &KnobModel, k: usize) -> (f64, f64) {
    let lambda = (BROAD[k] / km.unit[k]).powi(2);
    let a = km.hess[(k, k)] + 2.0 / lambda;
    (-km.grad[k] / a, 2.0 / a)
}

/// The stated latitude (deg), clock rate and gravity (ppm of the stated value: 0).
fn stated_values(prep: &Prepared) -> [f64; 3] {
    [
        (prep.site.latitude_rad.to_degrees() * 1e9).round() / 1e9,
        0.0,
        0.0,
    ]
}

/// Knob `k` misstated: `fit_gain` = f(0) − f(u*), `shift` the refits' parameter difference.
fn alternative(
    km: &KnobModel,
    k: usize,
    fit_gain: f64,
    shift: DVector<f64>,
    stated: f64,
) -> Alternative {
    let lambda = (BROAD[k] / km.unit[k]).powi(2);
    let (u, var) = estimate(km, k);
    let occam = (1.0 + lambda * km.hess[(k, k)] / 2.0).ln();
    let gain = fit_gain - u * u / lambda - occam - PRIOR_ODDS;
    let sens = km.sens.column(k);
    let (name, unit) = KNOBS[k];
    Alternative {
        effect: format!("{name} misstated"),
        evidence_gain: gain,
        weight: 0.0,
        reach: (0..shift.len())
            .map(|i| shift[i].abs() + 2.0 * var.sqrt() * sens[i].abs())
            .collect(),
        shift: shift.iter().copied().collect(),
        misstated: Some(Misstated {
            knob: name,
            unit,
            stated,
            value: stated + u * km.unit[k],
            sigma: var.sqrt() * km.unit[k],
            index: k,
        }),
    }
}

/// The misstatement to repair among `alts` (every explanation weighed, the catalog's and the
/// set-up's) and `rivals` (further explanations' gains, e.g. refitted catalog effects): the best
/// of all, ahead of every other by [`PLAUSIBLE_MARGIN`] and of the stated set-up by
/// [`MIN_EVIDENCE_GAIN`].
pub fn to_repair(alts: &[Alternative], rivals: &[(String, f64)]) -> Option<Misstated> {
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

/// `prep` and `cfg` with the misstated knob repaired: moved to the data's value, its prior the
/// data's 1σ, and the finding that names it among the measurements' findings (`alts`, `rivals`:
/// what it beat).
pub fn repair(
    prep: &Prepared,
    cfg: &Config,
    m: &Misstated,
    alts: &[Alternative],
    rivals: &[(String, f64)],
) -> (Prepared, Config) {
    let mut p = if m.index == 0 {
        // As it was weighed: gravity kept ([`profiled_latitude`]).
        super::setup::at_latitude_with(prep, m.value, false)
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
        .filter(|a| !a.misstated.is_some_and(|x| x.index == m.index))
        .map(|a| (a.effect.as_str(), a.evidence_gain))
        .chain(rivals.iter().map(|r| (r.0.as_str(), r.1)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    p.findings.push(Finding {
        kind: "set-up",
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
