//! The Gauss–Markov hyperparameters of `drift-markov` (stationary 1σ σ and correlation time τ)
//! from the data, by maximising the marginal likelihood of the measurements.
//!
//! `−2 ln L(σ, τ) = Σ_j (ν_jᵀ S_j⁻¹ ν_j + ln det S_j + 3 ln 2π)` is the prediction-error
//! decomposition of the Kalman filter linearised about the converged fit's trajectory
//! ([`crate::identify::neg2_log_evidence`], the same evidence every model choice uses): every
//! other state (the drift coefficients, the start angles, the Markov states themselves) is
//! integrated out by the filter, so only σ and τ are maximised over (type-II maximum likelihood).
//! The Gauss–Markov dynamics are linear, so changing σ or τ needs no new linearisation: one
//! forward pass per (σ, τ), about the same nominal.
//!
//! **Shared, not per axis.** One σ and one τ for the three axes: a 60-h run holds only 60 h/τ
//! correlation times per axis, so six free hyperparameters would each carry a 1σ of tens of
//! percent (and the azimuth axis' drift reaches the accelerometers only through the Earth's
//! turn, weakly); the wander of one gyro's axes comes from one rotor, suspension and thermal
//! environment, and three axes pooled give √3 more correlation times for the same two numbers.
//!
//! **Search.** In ln σ and ln τ within [`SIGMA_RANGE_DEGPH`] and [`TAU_RANGE_H`]: a 6×6 lattice
//! (steps of ×3, [`lattice`]) and then, from its best local minimum, Newton steps on a
//! quadratic fitted to a 3×3 stencil, until a step moves less than a tenth of the 1σ; from the
//! second best too, unless −2 ln L falls all the way from it to the first's optimum
//! ([`drains_into`]: the lattice sees one basin twice along the σ²/τ ridge). The
//! curvature there gives a 1σ, `cov(ln σ, ln τ) = 2 H⁻¹` (H the Hessian of −2 ln L); the 1σ
//! intervals printed are the profile likelihood's (−2 ln L minimised over the other parameter
//! rises by 1), since the ridge between σ and τ bends. About 80–130 passes in all (each point
//! once: [`Remembered`]), 0.3–0.6 s on a 60-h run at the 60-s period (a forward pass is 6–12
//! ms, two at once); the optimum found about the refitted
//! trajectory moved by < 1e-4 relative, so one round suffices.
//!
//! Only the model being fitted is tuned (`identify --with drift-markov`, a ladder rung that holds
//! it): the candidates' refits that choose an effect keep the catalog's σ and τ, so the choice of
//! effect is what it was. A misstated set-up is weighed with the wander tuned again at its own
//! set-up ([`retune_gain`]), and a repair tunes it again where it puts the set-up
//! ([`crate::assess`]).

use estimator_core::effects::{DriftMarkov, Effect};
use estimator_core::model::Model;
use nalgebra::{Matrix2, Vector2};
use serde::Serialize;

use super::{build_model, neg2_log_evidence, start_prior, Config, Identification, Prepared};
use crate::catalog::Catalog;

/// The effect whose σ and τ are estimated.
pub(crate) const NAME: &str = "drift-markov";
/// Range of σ searched, deg/h: from far below a detectable wander to a wander larger than the
/// paper's whole constant drift.
pub(crate) const SIGMA_RANGE_DEGPH: (f64, f64) = (1e-4, 0.3);
/// Range of τ searched, h: from a quarter hour (15 filter periods) to 100 h (beyond that a 60-h
/// run sees a random walk: only σ²/τ is determined).
pub(crate) const TAU_RANGE_H: (f64, f64) = (0.25, 100.0);

/// −2 ln L of `effects` with `drift-markov`'s σ (deg/h) and τ (h) set, linearised about the fit
/// `id` (one forward pass).
pub(crate) fn neg2_ln_l(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
    sigma_degph: f64,
    tau_h: f64,
) -> anyhow::Result<f64> {
    // Outside the search range nothing is evaluated: a τ far below it makes the propagation take
    // 8 sub-steps per τ (a profile 4σ out on a flat ridge asked for τ ~ e^-40 h and never ended).
    let within = |v: f64, (lo, hi): (f64, f64)| v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9);
    anyhow::ensure!(
        within(sigma_degph, SIGMA_RANGE_DEGPH) && within(tau_h, TAU_RANGE_H),
        "{NAME}: σ = {sigma_degph:e} deg/h, τ = {tau_h:e} h is outside the range searched"
    );
    let gm = DriftMarkov { sigma_degph, tau_h };
    let list = with_markov(effects, &gm);
    let model: Model<'_> = build_model(prep.site, &list, cfg)?;
    let (x0, p0) = start_prior(&model, prep, &prep.start_sigma());
    let pass = super::smoother::linearised_pass(
        &model,
        &prep.measurements,
        &id.trajectory,
        &x0,
        &p0,
        false,
    )?;
    Ok(neg2_log_evidence(&pass.innovations))
}

/// `effects` with `drift-markov` replaced by `gm`: the step every σ and τ tried, tuned or
/// retuned takes.
pub(crate) fn with_markov<'a>(
    effects: &[&'a dyn Effect],
    gm: &'a dyn Effect,
) -> Vec<&'a dyn Effect> {
    effects
        .iter()
        .map(|&e| if e.name() == NAME { gm } else { e })
        .collect()
}

/// Coarse grid of σ, deg/h: the catch-all's tries ([`crate::diagnose::select`]).
pub(crate) const GRID_SIGMA_DEGPH: [f64; 4] = [3e-4, 2e-3, 1e-2, 5e-2];
/// Coarse grid of τ, h.
pub(crate) const GRID_TAU_H: [f64; 4] = [0.5, 2.0, 8.0, 32.0];

/// The fitted hyperparameters.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct MarkovFit {
    /// Stationary 1σ of each axis' Gauss–Markov drift, deg/h.
    pub sigma_degph: f64,
    /// 1σ of σ from the curvature of −2 ln L at the optimum, deg/h (infinite where it is flat).
    pub sigma_sd_degph: f64,
    /// The 1σ (68 %) interval of σ from its profile likelihood, deg/h: where −2 ln L, minimised
    /// over τ, rises by 1. The likelihood's ridge bends (σ²/τ is what a long τ leaves), so this
    /// is the honest interval; the curvature's 1σ was up to 2× narrower on the long side.
    pub sigma_interval_degph: [f64; 2],
    /// Correlation time, h.
    pub tau_h: f64,
    /// 1σ of τ from the curvature, h.
    pub tau_sd_h: f64,
    /// The 1σ interval of τ from its profile likelihood, h.
    pub tau_interval_h: [f64; 2],
    /// Correlation of the estimates of ln σ and ln τ.
    pub correlation: f64,
    /// Whether σ or τ ended on a bound of its range (then its 1σ is a curvature at the bound).
    pub at_bound: bool,
    /// −2 ln L gain over the catalog's fixed σ = 0.01 deg/h, τ = 5 h.
    pub evidence_gain: f64,
    /// Forward passes spent.
    pub passes: usize,
    /// −2 ln L on the search's lattice ([`lattice`], row by row), where a retune at a nearby
    /// set-up looks again ([`retune_gain`]).
    #[serde(skip)]
    pub lattice: Lattice,
}

/// −2 ln L on the 6×6 lattice, τ by τ, σ within.
pub type Lattice = [f64; LATTICE_POINTS];

/// A point of the search: ln σ, ln τ.
type Point = Vector2<f64>;
/// Points evaluated, with their −2 ln L.
type Seen = Vec<(Point, f64)>;

/// Largest Newton iterations on the stencil before the search stops where it is.
const MAX_NEWTON: usize = 12;
/// A gain in −2 ln L below which a move to the stencil's best point is no move (a fiftieth of
/// the rise of 1 that bounds a 1σ interval): the fit's σ and τ, printed with their 1σ.
const STALL: f64 = 0.02;
/// The same for a retune's gain ([`retune_gain`]), which only weighs a misstatement: an
/// optimum found to 0.1 in −2 ln L reads its gain 60× finer than the plausible margin, and the
/// search took half its passes below that (a 60-h wander: 38 of 78 after the drop fell to 0.03).
const RETUNE_STALL: f64 = 0.1;
/// The stencil's least half-width (ln units) where it is looked at closer.
const MIN_HALF_WIDTH: f64 = 0.1;
/// Largest Newton step in ln σ or ln τ (the trust radius at the start).
const MAX_STEP_LN: f64 = 1.0;
/// The least trust radius tried before the search stops where it is.
const MIN_RADIUS: f64 = 0.03;
/// A Newton step below this fraction of the 1σ (in ln σ, ln τ) ends the search.
const STOP_SIGMA: f64 = 0.1;

fn bounds() -> (Point, Point) {
    (
        Point::new(SIGMA_RANGE_DEGPH.0.ln(), TAU_RANGE_H.0.ln()),
        Point::new(SIGMA_RANGE_DEGPH.1.ln(), TAU_RANGE_H.1.ln()),
    )
}

/// `p` moved into the range by at least `margin` from each bound (a stencil of half-width
/// `margin` about it stays in the range).
fn clamp(p: Point, margin: f64) -> Point {
    let (lo, hi) = bounds();
    Point::new(
        p[0].clamp(lo[0] + margin, hi[0] - margin),
        p[1].clamp(lo[1] + margin, hi[1] - margin),
    )
}

/// −2 ln L remembered by (σ, τ): each pass costs 6–12 ms on a 60-h run, and the search asks
/// for some points again (a stencil about the point a step gained at; the lattice point a
/// Newton search starts from). A pass that fails counts as +∞, as in [`evaluate`].
struct Remembered<'f, F> {
    f: &'f F,
    known: std::sync::Mutex<std::collections::HashMap<[u64; 2], f64>>,
}

impl<'f, F: Fn(f64, f64) -> anyhow::Result<f64> + Sync> Remembered<'f, F> {
    fn new(f: &'f F) -> Self {
        Self {
            f,
            known: Default::default(),
        }
    }

    fn at(&self, s: f64, t: f64) -> anyhow::Result<f64> {
        let key = [s.to_bits(), t.to_bits()];
        if let Some(&v) = self.known.lock().expect("not poisoned").get(&key) {
            return Ok(v);
        }
        let v = (self.f)(s, t).unwrap_or(f64::INFINITY);
        self.known.lock().expect("not poisoned").insert(key, v);
        Ok(v)
    }

    /// Passes run (each point once).
    fn passes(&self) -> usize {
        self.known.lock().expect("not poisoned").len()
    }
}

/// −2 ln L at several points, on rayon's pool (the passes are independent); a pass that fails
/// (a filter breakdown at an extreme σ) counts as +∞.
fn evaluate(points: &[Point], f: &(impl Fn(f64, f64) -> anyhow::Result<f64> + Sync)) -> Vec<f64> {
    use rayon::prelude::*;
    points
        .par_iter()
        .map(|p| f(p[0].exp(), p[1].exp()).unwrap_or(f64::INFINITY))
        .collect()
}

/// A quadratic fitted to −2 ln L on the 3×3 stencil of half-width `h` about `c`: its gradient and
/// Hessian at `c`, in ln units. `None` when a value is not finite.
fn stencil(
    c: Point,
    h: f64,
    f: &(impl Fn(f64, f64) -> anyhow::Result<f64> + Sync),
) -> Option<(Point, Matrix2<f64>, Seen)> {
    let offsets: Vec<Point> = (-1..=1)
        .flat_map(|i| (-1..=1).map(move |j| Point::new(f64::from(i), f64::from(j))))
        .collect();
    let points: Vec<Point> = offsets.iter().map(|o| c + o * h).collect();
    let values = evaluate(&points, f);
    if values.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let at = |i: i32, j: i32| values[((i + 1) * 3 + (j + 1)) as usize];
    // Least-squares quadratic on the 3×3 grid: the central differences of its row/column means.
    let gx = (0..3).map(|j| at(1, j - 1) - at(-1, j - 1)).sum::<f64>() / (6.0 * h);
    let gy = (0..3).map(|i| at(i - 1, 1) - at(i - 1, -1)).sum::<f64>() / (6.0 * h);
    let hxx = (0..3)
        .map(|j| at(1, j - 1) - 2.0 * at(0, j - 1) + at(-1, j - 1))
        .sum::<f64>()
        / (3.0 * h * h);
    let hyy = (0..3)
        .map(|i| at(i - 1, 1) - 2.0 * at(i - 1, 0) + at(i - 1, -1))
        .sum::<f64>()
        / (3.0 * h * h);
    let hxy = (at(1, 1) - at(1, -1) - at(-1, 1) + at(-1, -1)) / (4.0 * h * h);
    let seen = points.into_iter().zip(values).collect();
    Some((Point::new(gx, gy), Matrix2::new(hxx, hxy, hxy, hyy), seen))
}

/// The point of least −2 ln L among `seen`, if one is finite.
fn best(seen: &[(Point, f64)]) -> Option<(Point, f64)> {
    seen.iter()
        .copied()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .filter(|b| b.1.is_finite())
}

/// Newton steps on the 3×3 stencil from `c` (every point evaluated joins `seen`), until a step
/// moves less than [`STOP_SIGMA`] of the 1σ or would gain less than `stall` ([`STALL`] for a
/// fit, [`RETUNE_STALL`] for a retune's gain); returns the last
/// convex stencil's covariance of (ln σ, ln τ), 2 H⁻¹.
fn newton(
    mut c: Point,
    f: &(impl Fn(f64, f64) -> anyhow::Result<f64> + Sync),
    stall: f64,
    seen: &mut Seen,
) -> Option<Matrix2<f64>> {
    let mut h = 0.5;
    let mut radius = MAX_STEP_LN;
    let mut cov = None;
    for _ in 0..MAX_NEWTON {
        c = clamp(c, h);
        let Some((g, hess, points)) = stencil(c, h, f) else {
            break;
        };
        seen.extend(points);
        let convex = hess[(0, 0)] > 0.0 && hess.determinant() > 0.0;
        let Some(inv) = hess.try_inverse().filter(|_| convex) else {
            // Not convex here: move to the best point seen and look again; where the centre is
            // the best, look closer (a narrow bending ridge: a stencil of half-width 0.5 across
            // it is a saddle). A move that gains less than `stall` is no move (on a flat
            // ridge the best point wandered along it for every iteration allowed).
            cov = None;
            let here = seen[seen.len() - 5].1;
            match best(seen) {
                Some((b, v)) if b != c && v < here - stall => c = b,
                _ if h > MIN_HALF_WIDTH => h *= 0.5,
                _ => break,
            }
            continue;
        };
        let cv = inv * 2.0;
        let sd = Point::new(cv[(0, 0)].sqrt(), cv[(1, 1)].sqrt());
        cov = Some(cv);
        let full = -(inv * g);
        // The quadratic's own drop to its minimum, ½ gᵀH⁻¹g: below `stall` the optimum is
        // found to the evidence scale's resolution (along a flat ridge a tenth of the 1σ is
        // a long way, and the steps went on for every iteration allowed).
        if -0.5 * g.dot(&full) < stall {
            break;
        }
        let moved = |next: Point| {
            ((next - c)[0] / sd[0])
                .abs()
                .max(((next - c)[1] / sd[1]).abs())
        };
        // Newton's step within the trust radius, halved until it gains (a quadratic fitted
        // over a bending ridge can point past it: the search went back and forth between two
        // stencils for every iteration allowed).
        let here = seen[seen.len() - 5].1;
        let mut next = None;
        while radius >= MIN_RADIUS {
            let mut step = full;
            if step.amax() > radius {
                step *= radius / step.amax();
            }
            let trial = clamp(c + step, h);
            if moved(trial) < STOP_SIGMA {
                break;
            }
            let v = evaluate(&[trial], f)[0];
            seen.push((trial, v));
            if v < here {
                next = Some(trial);
                break;
            }
            radius *= 0.5;
        }
        let Some(next) = next else {
            // No step along Newton's direction gains: as where it is not convex, the stencil's
            // best point, else a closer look (a quadratic fitted across a bending ridge can
            // point off it; stopping there ended a 60-h run's τ at 40 h for 12).
            radius = MAX_STEP_LN;
            match best(seen) {
                Some((b, v)) if b != c && v < here - stall => c = b,
                _ if h > MIN_HALF_WIDTH => h *= 0.5,
                _ => break,
            }
            continue;
        };
        radius = (2.0 * radius).min(MAX_STEP_LN);
        let moved = moved(next);
        c = next;
        // A wide stencil while far (the quadratic over the ridge), about one 1σ once close (the
        // curvature the 1σ is read from).
        if moved < 1.0 {
            h = sd.max().clamp(0.1, 0.5);
        }
    }
    cov
}

/// Passes of one coordinate's profile interval: 2 sides × 2 offsets × 3 points.
const PROFILE_PASSES: usize = 12;

/// −2 ln L minimised over coordinate 1 − `i` with coordinate `i` at `p[i] + d`: a parabola
/// through three points about the ridge the curvature `cov` predicts, one conditional 1σ apart.
fn profile_points(p: Point, cov: &Matrix2<f64>, i: usize, d: f64) -> ([Point; 3], f64) {
    let j = 1 - i;
    let mean = p[j] + cov[(i, j)] / cov[(i, i)] * d;
    let w = (cov[(j, j)] - cov[(i, j)].powi(2) / cov[(i, i)])
        .max(0.0)
        .sqrt()
        .max(0.02);
    // Kept in the range searched (a flat ridge's curvature reaches far beyond it).
    let at = |o: f64| {
        let mut q = p;
        q[i] += d;
        q[j] = mean + o * w;
        clamp(q, 0.0)
    };
    ([at(-1.0), at(0.0), at(1.0)], w)
}

/// The minimum of the parabola through values `v` at −w, 0, w (the least value if it opens down
/// or its vertex lies beyond ±2w).
fn parabola_min(v: [f64; 3]) -> f64 {
    let a = (v[0] + v[2] - 2.0 * v[1]) / 2.0;
    let b = (v[2] - v[0]) / 2.0;
    let least = v.iter().copied().fold(f64::INFINITY, f64::min);
    if a > 0.0 && (b / (2.0 * a)).abs() <= 2.0 {
        (v[1] - b * b / (4.0 * a)).min(least)
    } else {
        least
    }
}

/// The 1σ interval of coordinate `i` (ln units) from its profile likelihood: on each side the
/// profile at one and two curvature-1σ, a quadratic in the offset through them and the optimum,
/// solved for a rise of 1 (at most 4 curvature-1σ out, and within the range searched).
fn profile_interval(
    p: Point,
    f_best: f64,
    cov: &Matrix2<f64>,
    i: usize,
    f: &(impl Fn(f64, f64) -> anyhow::Result<f64> + Sync),
) -> [f64; 2] {
    let sd = cov[(i, i)].sqrt();
    let offsets = [-2.0, -1.0, 1.0, 2.0];
    let points: Vec<Point> = offsets
        .iter()
        .flat_map(|k| profile_points(p, cov, i, k * sd).0)
        .collect();
    let values = evaluate(&points, f);
    let rise: Vec<f64> = values
        .chunks(3)
        .map(|v| parabola_min([v[0], v[1], v[2]]) - f_best)
        .collect();
    let reach = |d1: f64, d2: f64| {
        // g(k) = α k + β k², g(1) = d1, g(2) = d2; the k where g = 1.
        if !(d1 > 0.0 && d2.is_finite()) {
            return 1.0;
        }
        let beta = (d2 - 2.0 * d1) / 2.0;
        let alpha = d1 - beta;
        let k = if beta.abs() < 1e-12 {
            1.0 / alpha
        } else {
            let disc = alpha * alpha + 4.0 * beta;
            if disc < 0.0 {
                4.0
            } else {
                (-alpha + disc.sqrt()) / (2.0 * beta)
            }
        };
        if k.is_finite() && k > 0.0 {
            k.clamp(0.25, 4.0)
        } else {
            4.0
        }
    };
    let (lo, hi) = bounds();
    [
        (p[i] - reach(rise[1], rise[0]) * sd).max(lo[i]),
        (p[i] + reach(rise[2], rise[3]) * sd).min(hi[i]),
    ]
}

/// The optimum of the search: (ln σ, ln τ), its −2 ln L, the curvature's covariance there (if
/// convex), the −2 ln L at the catalog's σ and τ, and the passes spent.
struct Optimum {
    p: Point,
    f_best: f64,
    cov: Option<Matrix2<f64>>,
    f_catalog: f64,
    passes: usize,
    lattice: Lattice,
}

/// The lattice the search starts on: σ and τ each in steps of ×3 ([`LATTICE_SIGMA_DEGPH`] ×
/// [`LATTICE_TAU_H`]). Finer than the catch-all's grid ([`GRID_SIGMA_DEGPH`]): −2 ln L can have
/// two basins, a short wander and a long one along the σ²/τ ridge, and the ×4–×7 grid missed the
/// short one (a 48-h run with a 3.2-h sine: the search ended at the grid point σ 2e-3 deg/h,
/// τ 8 h on a saddle, 40 above σ 6.8e-4 deg/h, τ 0.5 h).
fn lattice() -> Vec<Vec<Point>> {
    LATTICE_TAU_H
        .iter()
        .map(|t| {
            LATTICE_SIGMA_DEGPH
                .iter()
                .map(|s| Point::new(s.ln(), t.ln()))
                .collect()
        })
        .collect()
}

/// The lattice's σ, deg/h.
const LATTICE_SIGMA_DEGPH: [f64; 6] = [1.5e-4, 4.5e-4, 1.35e-3, 4e-3, 1.2e-2, 3.6e-2];
/// The lattice's τ, h.
const LATTICE_TAU_H: [f64; 6] = [0.3, 0.9, 2.7, 8.1, 24.0, 73.0];
/// The lattice's points.
pub const LATTICE_POINTS: usize = LATTICE_SIGMA_DEGPH.len() * LATTICE_TAU_H.len();
/// How far above the lattice's best a point of an earlier search at a nearby set-up may lie and
/// still be looked at again in a retune ([`retune_gain`]). A misstatement moves −2 ln L at a
/// lattice point by about what it gains (at most 23 in the runs where retuning mattered: a
/// latitude 0.1° off under a 5.7-h sine moved the wander's optimum from τ 19 h to 1.0 h); 100
/// leaves four times that, and skips the points of the lattice that lie thousands above.
const LATTICE_NEAR: f64 = 100.0;
/// Basins searched at most: the lattice's best local minima, each a Newton search's start.
const STARTS: usize = 2;
/// How far above the best lattice value (−2 ln L) a second basin is still searched.
const SECOND_BASIN: f64 = 20.0;

/// The lattice's local minima (no lower neighbour along σ or τ), best first, at most [`STARTS`].
fn starts(values: &[Vec<f64>]) -> Vec<(usize, usize)> {
    let (rows, cols) = (values.len(), values[0].len());
    let mut minima: Vec<(usize, usize)> = (0..rows)
        .flat_map(|i| (0..cols).map(move |j| (i, j)))
        .filter(|&(i, j)| {
            let v = values[i][j];
            let lower = |a: Option<usize>, b: Option<usize>| {
                matches!((a, b), (Some(a), Some(b)) if a < rows && b < cols && values[a][b] < v)
            };
            v.is_finite()
                && !lower(i.checked_sub(1), Some(j))
                && !lower(Some(i + 1), Some(j))
                && !lower(Some(i), j.checked_sub(1))
                && !lower(Some(i), Some(j + 1))
        })
        .collect();
    minima.sort_by(|a, b| values[a.0][a.1].total_cmp(&values[b.0][b.1]));
    minima.truncate(STARTS);
    minima
}

/// The lattice, then Newton on the stencil from each of its best basins (see the module docs),
/// for the −2 ln L `f`, each search ending once a step would gain less than `stall`. A second
/// basin is searched only where the way from it to the first's optimum rises
/// ([`drains_into`]).
fn optimum(
    f: &(impl Fn(f64, f64) -> anyhow::Result<f64> + Sync),
    stall: f64,
    earlier: Option<&Lattice>,
) -> anyhow::Result<Optimum> {
    let remembered = Remembered::new(f);
    let f = &|s: f64, t: f64| remembered.at(s, t);
    let catalog = DriftMarkov::default();
    let rows = lattice();
    let mut points: Vec<Point> = rows.iter().flatten().copied().collect();
    points.push(Point::new(catalog.sigma_degph.ln(), catalog.tau_h.ln()));
    // With an earlier search's lattice at a nearby set-up: only its points near its best (the
    // rest count as +∞, never a start), and the catalog's.
    let wanted: Vec<bool> = match earlier {
        Some(e) => {
            let low = e.iter().copied().fold(f64::INFINITY, f64::min);
            e.iter()
                .map(|&v| v <= low + LATTICE_NEAR)
                .chain(std::iter::once(true))
                .collect()
        }
        None => vec![true; points.len()],
    };
    let asked: Vec<Point> = points
        .iter()
        .zip(&wanted)
        .filter(|(_, &w)| w)
        .map(|(p, _)| *p)
        .collect();
    let mut got = evaluate(&asked, f).into_iter();
    let values: Vec<f64> = wanted
        .iter()
        .map(|&w| match w {
            true => got.next().unwrap_or(f64::INFINITY),
            false => f64::INFINITY,
        })
        .collect();
    let f_catalog = values[points.len() - 1];
    let mut lattice_values: Lattice = [f64::INFINITY; LATTICE_POINTS];
    lattice_values.copy_from_slice(&values[..LATTICE_POINTS]);
    let cols = LATTICE_SIGMA_DEGPH.len();
    let grid: Vec<Vec<f64>> = values[..points.len() - 1]
        .chunks(cols)
        .map(<[f64]>::to_vec)
        .collect();
    let begin = starts(&grid);
    if begin.is_empty() {
        anyhow::bail!("{NAME}: the filter fails at every σ, τ of the lattice");
    }
    let mut seen: Seen = points
        .into_iter()
        .zip(values)
        .filter(|(_, v)| v.is_finite())
        .collect();
    // Each basin's search; the one whose best point is lowest gives the curvature.
    let mut found: Vec<(f64, Option<Matrix2<f64>>)> = vec![];
    let first = begin[0];
    for (i, j) in begin {
        // Another basin only where the lattice finds it near the first (within the margin
        // that keeps an explanation plausible): far above, it cannot end lowest.
        if grid[i][j] > grid[first.0][first.1] + SECOND_BASIN {
            continue;
        }
        if let Some(lowest) = best(&seen).filter(|_| !found.is_empty()) {
            let (drains, way) = drains_into((rows[i][j], grid[i][j]), lowest, stall, f);
            seen.extend(way);
            if drains {
                continue;
            }
        }
        let mut own: Seen = vec![];
        let cov = newton(rows[i][j], f, stall, &mut own);
        let low = best(&own).map_or(grid[i][j], |b| b.1.min(grid[i][j]));
        found.push((low, cov));
        seen.extend(own);
    }
    let Some((p, f_best)) = best(&seen) else {
        anyhow::bail!("{NAME}: no finite likelihood");
    };
    let cov = found
        .into_iter()
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .and_then(|(_, cov)| cov);
    Ok(Optimum {
        p,
        f_best,
        cov,
        f_catalog,
        passes: remembered.passes(),
        lattice: lattice_values,
    })
}

/// Points on the way from a second basin of the lattice to the first's optimum.
const WAY_POINTS: usize = 4;

/// Whether −2 ln L falls all the way (evenly spaced points in ln σ, ln τ) from the lattice's
/// point `from` (with its value) towards `to` (the optimum found so far, with its value), and
/// ends no lower than `to` less `stall` (the resolution `to` was found to): then `from` lies
/// on that basin's slope, not in a basin of its own, and its Newton search would only walk down
/// to the same optimum (a 60-h wander: 111 passes along the σ²/τ ridge from τ 73 h to the first
/// search's 3.7 h). A rise on the way, or a point well below `to`, keeps the second search (two
/// basins: a wander tuned in the wrong one left a misstated latitude's weight 0 and DXx 29σ
/// off). The points evaluated are returned to join the search's.
fn drains_into(
    from: (Point, f64),
    to: (Point, f64),
    stall: f64,
    f: &(impl Fn(f64, f64) -> anyhow::Result<f64> + Sync),
) -> (bool, Seen) {
    let way: Vec<Point> = (1..=WAY_POINTS)
        .map(|k| from.0 + (to.0 - from.0) * (k as f64 / (WAY_POINTS + 1) as f64))
        .collect();
    let values = evaluate(&way, f);
    let mut last = from.1;
    let falls = values.iter().all(|&v| {
        let lower = v <= last;
        last = v;
        lower
    });
    (
        falls && last >= to.1 - stall,
        way.into_iter().zip(values).collect(),
    )
}

/// Maximises the marginal likelihood over σ and τ about the fit `id` of `effects` (which hold
/// `drift-markov`): [`optimum`], then the profile intervals.
pub(crate) fn fit(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
) -> anyhow::Result<MarkovFit> {
    let f = |s: f64, t: f64| neg2_ln_l(prep, effects, cfg, id, s, t);
    let Optimum {
        p,
        f_best,
        cov,
        f_catalog,
        passes,
        lattice,
    } = optimum(&f, STALL, None)?;
    let (lo, hi) = bounds();
    let at_bound = (0..2).any(|i| p[i] <= lo[i] + 1e-6 || p[i] >= hi[i] - 1e-6);
    let (sigma, tau) = (p[0].exp(), p[1].exp());
    let (sd, correlation) = match cov {
        Some(cv) => (
            Point::new(cv[(0, 0)].sqrt(), cv[(1, 1)].sqrt()),
            cv[(0, 1)] / (cv[(0, 0)] * cv[(1, 1)]).sqrt(),
        ),
        None => (Point::new(f64::INFINITY, f64::INFINITY), f64::NAN),
    };
    let interval = |i: usize| match cov {
        Some(cv) if !at_bound => profile_interval(p, f_best, &cv, i, &f),
        _ => [f64::NEG_INFINITY, f64::INFINITY],
    };
    let (si, ti) = (interval(0), interval(1));
    Ok(MarkovFit {
        sigma_degph: sigma,
        sigma_sd_degph: sigma * sd[0],
        sigma_interval_degph: si.map(f64::exp),
        tau_h: tau,
        tau_sd_h: tau * sd[1],
        tau_interval_h: ti.map(f64::exp),
        correlation,
        at_bound,
        evidence_gain: f_catalog - f_best,
        passes: passes
            + if cov.is_some() && !at_bound {
                2 * PROFILE_PASSES
            } else {
                0
            },
        lattice,
    })
}

/// When `effects` hold `drift-markov` and `id` is converged: σ and τ fitted ([`fit`]), the
/// effect replaced by one with them and the model refitted there (from `id`'s trajectory).
/// Otherwise everything is returned as it is (the clean path does no work here). The tuned
/// effect is owned by `catalog` ([`Catalog::tuned_markov`]).
pub fn tune<'e>(
    catalog: &'e Catalog,
    prep: &Prepared,
    effects: &[&'e dyn Effect],
    cfg: &Config,
    id: Identification,
) -> anyhow::Result<(Vec<&'e dyn Effect>, Identification)> {
    if id.trajectory.is_empty() || !effects.iter().any(|e| e.name() == NAME) {
        return Ok((effects.to_vec(), id));
    }
    let gm = fit(prep, effects, cfg, &id)?;
    let list = with_markov(effects, catalog.tuned_markov(gm.sigma_degph, gm.tau_h));
    let model = build_model(prep.site, &list, cfg)?;
    let mut refit = super::identify_from(&model, prep, cfg, &id)?;
    refit.markov = Some(gm);
    Ok((list, refit))
}

/// What tuning σ and τ again at the set-up of `at` gains, on the linearisation about the fit
/// `id` ([`neg2_ln_l`]): −2 ln L at the σ and τ `id` was fitted with less that at the optimum
/// there (≥ 0), and the optimum. `None` where `id`'s `drift-markov` was not tuned (not in the
/// model) or the search fails.
///
/// A wander tuned at the stated set-up stretches to absorb a misstated one: a latitude 0.1° off
/// under a 5.7-h sine drift had τ = 19 h at the stated latitude and 1.0 h at the true one, and
/// the misstated latitude, refitted with the stretched wander held, fell 23 in −2 ln p(y) short
/// of its own wander (gain −11.6, weight 0): the run was trusted with DXx 29σ off. Each
/// misstatement is weighed with its own wander ([`crate::diagnose::misstated`]).
pub(crate) fn retune_gain(
    at: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
) -> Option<(f64, DriftMarkov)> {
    let gm = id.markov.as_ref()?;
    if !effects.iter().any(|e| e.name() == NAME) {
        return None;
    }
    let f = |s: f64, t: f64| neg2_ln_l(at, effects, cfg, id, s, t);
    let (held, best) = rayon::join(
        || f(gm.sigma_degph, gm.tau_h),
        || optimum(&f, RETUNE_STALL, Some(&gm.lattice)),
    );
    let best = best.ok()?;
    let tuned = DriftMarkov {
        sigma_degph: best.p[0].exp(),
        tau_h: best.p[1].exp(),
    };
    Some(((held.ok()? - best.f_best).max(0.0), tuned))
}

/// The refit of `effects` on `at` with `drift-markov` as `gm` ([`crate::identify::setup::refit`]).
pub(crate) fn refit_with(
    at: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
    gm: &DriftMarkov,
) -> anyhow::Result<(f64, nalgebra::DVector<f64>)> {
    super::setup::refit(at, &with_markov(effects, gm), cfg, id)
}

impl MarkovFit {
    /// One line for the text output: the estimates ± their 1σ (digits from the 1σ,
    /// [`crate::format::pm`]) and their profile-likelihood intervals, or the bound they ended on.
    pub fn line(&self) -> String {
        use crate::format::sig;
        let head = format!(
            "{NAME}: σ and τ fitted by marginal likelihood, shared by the three axes ({} filter passes; range σ {}–{} deg/h, τ {}–{} h)",
            self.passes,
            sig(SIGMA_RANGE_DEGPH.0, 2),
            sig(SIGMA_RANGE_DEGPH.1, 2),
            sig(TAU_RANGE_H.0, 2),
            sig(TAU_RANGE_H.1, 2)
        );
        if self.at_bound {
            return format!(
                "{head}: σ = {} deg/h, τ = {} h — at the edge of the range: no Gauss–Markov wander this run can measure (no 1σ)",
                sig(self.sigma_degph, 2),
                sig(self.tau_h, 2)
            );
        }
        let [s0, s1] = self.sigma_interval_degph;
        let [t0, t1] = self.tau_interval_h;
        format!(
            "{head}: σ = {} deg/h (1σ interval {}–{}), τ = {} h (1σ interval {}–{}; correlation of ln σ, ln τ {:.2}); −2 ln L {:.1} below the catalog's σ 0.01 deg/h, τ 5 h",
            crate::format::pm(self.sigma_degph, self.sigma_sd_degph),
            sig(s0, 2),
            sig(s1, 2),
            crate::format::pm(self.tau_h, self.tau_sd_h),
            sig(t0, 2),
            sig(t1, 2),
            self.correlation,
            self.evidence_gain
        )
    }
}

#[cfg(test)]
mod line_tests {
    use super::MarkovFit;

    /// `identify`'s line prints σ and τ as every other estimate: value ± 1σ with the digits the
    /// 1σ gives (two significant digits of it) and their units, then the profile interval.
    #[test]
    fn sigma_and_tau_are_printed_with_their_one_sigma() {
        let gm = MarkovFit {
            sigma_degph: 0.0123,
            sigma_sd_degph: 0.0021,
            sigma_interval_degph: [0.0095, 0.0161],
            tau_h: 4.87,
            tau_sd_h: 1.3,
            tau_interval_h: [3.6, 7.1],
            correlation: 0.42,
            at_bound: false,
            evidence_gain: 3.2,
            passes: 40,
            lattice: [0.0; super::LATTICE_POINTS],
        };
        let line = gm.line();
        assert!(
            line.contains("σ = 0.0123 ± 0.0021 deg/h (1σ interval 0.0095–0.016)"),
            "{line}"
        );
        assert!(
            line.contains("τ = 4.9 ± 1.3 h (1σ interval 3.6–7.1;"),
            "{line}"
        );
    }
}

#[cfg(test)]
mod search_tests {
    use super::*;

    /// Where a search ended, for a failed assertion.
    fn ended(o: &Optimum) -> String {
        format!(
            "ended at σ {:e}, τ {}, −2 ln L {} ({} passes)",
            o.p[0].exp(),
            o.p[1].exp(),
            o.f_best,
            o.passes
        )
    }

    /// A narrow ridge along σ²/τ, narrower than the lattice's step, with its lowest point
    /// between lattice points: a stencil of half-width 0.5 across it is a saddle. The search
    /// stopped there (a 48-h run: σ 2e-3 deg/h, τ 8 h, 40 above the optimum at σ 6.8e-4,
    /// τ 0.5). It must now end within 0.5 of the lowest −2 ln L (what the evidence scale reads:
    /// a twelfth of the margin that keeps an explanation plausible), on the ridge (within its
    /// 1σ along τ, 0.32 in ln τ here).
    #[test]
    fn the_search_follows_a_narrow_ridge_to_its_lowest_point() {
        let (s0, t0) = (6.8e-4f64.ln(), 0.5f64.ln());
        let f = |s: f64, t: f64| -> anyhow::Result<f64> {
            let across = 2.0 * (s.ln() - s0) - (t.ln() - t0);
            let along = t.ln() - t0;
            Ok(-100.0 * (-(across / 0.6).powi(2)).exp() + 10.0 * along * along)
        };
        let o = optimum(&f, STALL, None).unwrap();
        assert!(
            o.f_best < -100.0 + 0.5 && (o.p[1] - t0).abs() < 0.32,
            "ended at σ {:e}, τ {} ({} passes)",
            o.p[0].exp(),
            o.p[1].exp(),
            o.passes
        );
    }

    /// A bending ridge (a banana in ln σ, ln τ): Newton's step from a stencil across it points
    /// past the ridge, and the search went back and forth between two stencils for every
    /// iteration allowed (a 48-h run at 30 s: 108 passes per start, 0.3 above the optimum found
    /// with a trust region). It must end within 0.5 of the lowest −2 ln L (a twelfth of the
    /// margin that keeps an explanation plausible) and within the passes of the lattice and two
    /// searches that converge (37 + 2 × 60).
    #[test]
    fn the_search_ends_at_the_lowest_point_of_a_bending_ridge() {
        let (s0, t0) = (1e-3f64.ln(), 20f64.ln());
        let f = |s: f64, t: f64| -> anyhow::Result<f64> {
            let (x, y) = (s.ln() - s0, t.ln() - t0);
            Ok(50.0 * (2.0 * x - y - 0.3 * y * y).powi(2) + 2.0 * y * y)
        };
        let o = optimum(&f, STALL, None).unwrap();
        assert!(o.f_best < 0.5 && o.passes <= 37 + 2 * 60, "{}", ended(&o));
    }

    /// A single basin along the σ²/τ ridge that several lattice points lie near, each a local
    /// minimum of the lattice (a 60-h wander's: τ 8.1 h and 73 h, and both searches walked to
    /// the same optimum, 78 and 115 passes). The second lies on the first's slope: it must not be
    /// searched again, and the optimum must be found as before (within 0.5, a twelfth of the
    /// plausible margin). Budget: the lattice (37), one search — −2 ln L is exactly quadratic
    /// here, so Newton's first step lands on the optimum and a second stencil confirms it (2 × 9)
    /// — and the way's points; searching the second start as well took 84.
    #[test]
    fn a_basin_the_lattice_sees_twice_is_searched_once() {
        let (s0, t0) = (8e-4f64.ln(), 3.7f64.ln());
        let f = |s: f64, t: f64| -> anyhow::Result<f64> {
            let (x, y) = (s.ln() - s0, t.ln() - t0);
            Ok(200.0 * (2.0 * x - y).powi(2) + 1.5 * y * y)
        };
        let o = optimum(&f, STALL, None).unwrap();
        assert!(
            o.f_best < 0.5 && o.passes <= 37 + 2 * 9 + WAY_POINTS,
            "{}",
            ended(&o)
        );
    }

    /// Two basins: a broad one the lattice reads lowest, and a narrow deeper one between
    /// lattice points that the lattice reads 12 above it (within [`SECOND_BASIN`]). The way
    /// between them rises, so the second must still be searched and the search must end in it
    /// (within 0.5 of its bottom): a wander tuned in the wrong basin left a misstated latitude
    /// weight 0 and DXx 29σ off.
    #[test]
    fn a_second_basin_behind_a_rise_is_still_searched() {
        let a = Point::new(1.35e-3f64.ln(), 2.7f64.ln());
        let b = Point::new(-4.90, 3.70);
        let f = |s: f64, t: f64| -> anyhow::Result<f64> {
            let p = Point::new(s.ln(), t.ln());
            let well = |c: Point, w: f64| (-(p - c).norm_squared() / w).exp();
            Ok(-30.0 * well(a, 1.3) - 50.0 * well(b, 0.5))
        };
        let o = optimum(&f, STALL, None).unwrap();
        assert!(
            o.f_best < -50.0 + 0.5 && (o.p - b).norm() < 0.3,
            "{}",
            ended(&o)
        );
    }

    /// A retune at a nearby set-up looks again only at the lattice points the earlier search
    /// found within [`LATTICE_NEAR`] of its best, and must still find a basin that was 18 above
    /// there and is lowest now (the misstated latitude under a 5.7-h sine: τ 19 h at the stated
    /// latitude, 1.0 h at the true one), within 0.5 of its bottom; the points thousands above
    /// are not asked for again.
    #[test]
    fn a_retune_finds_the_basin_that_became_lowest_and_skips_the_far_points() {
        let (a, b) = (
            Point::new(1.35e-3f64.ln(), 24f64.ln()),
            Point::new(4.5e-4f64.ln(), 0.9f64.ln()),
        );
        // Two wells, 18 apart, on a bowl that rises to hundreds away from them.
        let surface = |deep_a: f64, deep_b: f64| {
            move |s: f64, t: f64| -> anyhow::Result<f64> {
                let p = Point::new(s.ln(), t.ln());
                let well = |c: Point| (-(p - c).norm_squared() / 0.8).exp();
                let centre = Point::new(7e-4f64.ln(), 4f64.ln());
                Ok(10.0 * (p - centre).norm_squared() - deep_a * well(a) - deep_b * well(b))
            }
        };
        let stated = optimum(&surface(400.0, 370.0), STALL, None).unwrap();
        assert!((stated.p - a).norm() < 0.5, "the stated set-up's basin");
        let asked = std::sync::Mutex::new(0usize);
        let moved = surface(370.0, 400.0);
        let counted = |s: f64, t: f64| {
            *asked.lock().unwrap() += 1;
            moved(s, t)
        };
        let o = optimum(&counted, RETUNE_STALL, Some(&stated.lattice)).unwrap();
        let bottom = optimum(&moved, STALL, None).unwrap().f_best;
        assert!(
            (o.p - b).norm() < 0.5 && o.f_best < bottom + 0.5,
            "ended at σ {:e}, τ {}, −2 ln L {} (the bottom {bottom})",
            o.p[0].exp(),
            o.p[1].exp(),
            o.f_best
        );
        let far = stated
            .lattice
            .iter()
            .filter(|v| {
                **v > stated.lattice.iter().copied().fold(f64::INFINITY, f64::min) + LATTICE_NEAR
            })
            .count();
        assert!(
            far > LATTICE_POINTS / 2,
            "the bowl leaves far points: {far}"
        );
        assert!(
            *asked.lock().unwrap() <= o.passes && o.passes < stated.passes,
            "{} passes, the full search {}",
            o.passes,
            stated.passes
        );
    }

    /// A flat ridge (a wander the run hardly constrains: seed 9509, 36 h at 10 s, whose rung
    /// with `drift-markov` never ended) gives a curvature 1σ of e^20 in ln τ; the profile 4σ out
    /// asked for τ ~ e^-40 h, and one pass at it took 8 propagation sub-steps per τ. Every point
    /// the profile evaluates must lie in the range searched, and the interval must end there.
    #[test]
    fn the_profile_stays_in_the_range_searched_on_a_flat_ridge() {
        let asked = std::sync::Mutex::new(vec![]);
        let f = |s: f64, t: f64| -> anyhow::Result<f64> {
            asked.lock().unwrap().push((s, t));
            Ok(1e-6 * (s.ln() - t.ln()).powi(2))
        };
        let p = Point::new(0.01f64.ln(), 10f64.ln());
        let cov = Matrix2::new(4e8, 3.9e8, 3.9e8, 4e8);
        let (lo, hi) = bounds();
        for i in 0..2 {
            let [a, b] = profile_interval(p, 0.0, &cov, i, &f);
            assert!(
                a >= lo[i] && b <= hi[i],
                "interval {a}..{b} of coordinate {i}"
            );
        }
        let asked = asked.into_inner().unwrap();
        assert_eq!(asked.len(), 2 * PROFILE_PASSES);
        for (s, t) in asked {
            let inside =
                |v: f64, (l, h): (f64, f64)| v >= l * (1.0 - 1e-9) && v <= h * (1.0 + 1e-9);
            assert!(
                inside(s, SIGMA_RANGE_DEGPH) && inside(t, TAU_RANGE_H),
                "evaluated at σ = {s:e}, τ = {t:e}"
            );
        }
    }
}
