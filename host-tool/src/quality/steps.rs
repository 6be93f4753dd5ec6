//! The noise at the filter period and steps in the filter-period means.
//!
//! Third differences of consecutive means remove the slow gravity-cone signal (~7e-7 m/s² at
//! 60 s) and keep the means' own noise with variance 20σ_m². Compared with the raw noise over
//! √n they reveal quantised or correlated noise (the floor the filter must use), and an isolated
//! jump of size J leaves the pattern (J, −2J, J): a bias step.

use estimator_core::robust;
use estimator_core::Measurement;
use rayon::prelude::*;

use super::{axis_name, Action, Finding, Kind};

/// A step is reported beyond this many robust 1σ of the third differences.
pub(crate) const STEP_SIGMAS: f64 = 8.0;
/// The means' scatter must differ from white raw noise by at least this factor to replace it.
pub(crate) const MEAN_NOISE_FACTOR: f64 = 1.5;

/// One third difference of four consecutive means of an axis.
#[derive(Clone, Copy, Debug)]
struct Diff {
    /// Index of the first of the four means.
    k: usize,
    /// The difference as taken (m/s²): on an even grid x₃ − 3x₂ + 3x₁ − x₀, which a jump J
    /// makes −J, 2J or −J.
    raw: f64,
    /// The same difference rescaled to the noise it would have were its four means full windows
    /// of the typical count (m/s²): `raw` · √(20 / (n · Σ cᵢ²/nᵢ)), cᵢ its coefficients, nᵢ
    /// the means' sample counts, n the median count. Every threshold and scatter is taken on
    /// this: a partial last (or first) filter period, or one with rejected samples, has a mean
    /// √(n/nᵢ) noisier. Unweighted, the last period's single sample of a 60-h run at 1 s (√60 ≈
    /// 7.7× the noise of a full mean, on an uneven grid that amplifies it 1.8× more) made 5 of
    /// 60 clean runs report a "step" at the end (issue 27).
    z: f64,
}

/// Third differences of each axis over runs of four consecutive means ([`Diff`]). On an even
/// grid of spacing h this is x₃ − 3x₂ + 3x₁ − x₀; on an uneven one (a window with rejected
/// samples, cut short by a gap or by the end of the record is tagged off the grid) it is the
/// third divided difference times 6h³, h = (t₃ − t₀)/3, which also vanishes on a line or a
/// parabola. Runs with a spacing outside [h/2, 3h/2] (a gap) are skipped. Skipping every uneven
/// run instead once hid a 2e-2 m/s² bias step: the samples at the jump are rejected as
/// glitches, which moves exactly the step's window off the grid.
fn third_differences(means: &[Measurement], axis: usize) -> Vec<Diff> {
    let typical = typical_count(means);
    let mut out = vec![];
    for k in 0..means.len().saturating_sub(3) {
        let t = |i: usize| means[k + i].t_s;
        let h = (t(3) - t(0)) / 3.0;
        let regular = h > 0.0 && (0..3).all(|i| (t(i + 1) - t(i) - h).abs() <= 0.5 * h);
        if !regular {
            continue;
        }
        let x = |i: usize| means[k + i].specific_force[axis];
        let even = (0..3).all(|i| ((t(i + 1) - t(i)) / h - 1.0).abs() < 1e-3);
        let c: [f64; 4] = if even {
            [-1.0, 3.0, -3.0, 1.0]
        } else {
            // Σ xᵢ / Πⱼ≠ᵢ (tᵢ − tⱼ), scaled to the even grid's form.
            core::array::from_fn(|i| {
                let den: f64 = (0..4).filter(|&j| j != i).map(|j| t(i) - t(j)).product();
                6.0 * h * h * h / den
            })
        };
        let raw: f64 = (0..4).map(|i| c[i] * x(i)).sum();
        // Σ cᵢ²/nᵢ against the even grid's 20/n: the variance of this difference in units of
        // a full-window one's.
        let var: f64 = (0..4)
            .map(|i| c[i] * c[i] / f64::from(means[k + i].count.max(1)))
            .sum();
        let rel = (var * typical / 20.0).sqrt();
        let z = if rel > 0.0 { raw / rel } else { raw };
        out.push(Diff { k, raw, z });
    }
    out
}

/// The median sample count of a filter-period mean (the full window's, whatever the partial
/// first and last ones hold).
pub(crate) fn typical_count(means: &[Measurement]) -> f64 {
    let mut counts: Vec<u32> = means.iter().map(|m| m.count).collect();
    if counts.is_empty() {
        return 1.0;
    }
    robust::median_by(&mut counts, Ord::cmp, f64::from).max(1.0)
}

/// 1σ of a full-window mean per axis from the scatter of the means' third differences (robust);
/// 0 on a skipped axis or one with too few means.
pub(crate) fn mean_sigma(means: &[Measurement], skip: &[bool; 3]) -> [f64; 3] {
    core::array::from_fn(|a| {
        let d = third_differences(means, a);
        if skip[a] || d.len() < 30 {
            0.0
        } else {
            sigma_of_z(&d) / 20f64.sqrt()
        }
    })
}

/// 1σ of the rescaled differences ([`Diff::z`]) from the median of their sizes.
fn sigma_of_z(d: &[Diff]) -> f64 {
    let mut v: Vec<f64> = d.iter().map(|x| x.z.abs()).collect();
    robust::sigma_from_abs(&mut v)
}

/// Compares the means' scatter with raw noise/√n; returns the means' own 1σ per axis to use when
/// they disagree (other axes keep raw/√n), with a finding.
pub(crate) fn check_mean_noise(
    means: &[Measurement],
    raw_sigma: &[f64; 3],
    findings: &mut Vec<Finding>,
) -> Option<[f64; 3]> {
    if means.is_empty() {
        return None;
    }
    let n = typical_count(means);
    let mut out = [0.0; 3];
    let mut any = vec![];
    for a in 0..3 {
        let d = third_differences(means, a);
        let white = raw_sigma[a] / n.sqrt();
        out[a] = white;
        if d.len() < 30 {
            continue;
        }
        let emp = sigma_of_z(&d) / 20f64.sqrt();
        // The MAD of overlapping third differences: relative 1σ ≈ 2/√N.
        let tol = MEAN_NOISE_FACTOR
            .ln()
            .max(6.0 * 2.0 / (d.len() as f64).sqrt());
        if (emp / white).ln().abs() > tol {
            out[a] = emp;
            any.push(format!("{} {:.2}×", axis_name(a), emp / white));
        }
    }
    if any.is_empty() {
        return None;
    }
    findings.push(Finding {
        kind: Kind::MeanNoise,
        message: format!(
            "the filter-period means scatter unlike white raw noise would ({}; raw 1σ [{:.2e}, {:.2e}, {:.2e}] m/s^2 over √{n:.0}): \
             quantised outputs or correlated noise; the filter uses the means' own scatter [{:.2e}, {:.2e}, {:.2e}] m/s^2",
            any.join(", "),
            raw_sigma[0],
            raw_sigma[1],
            raw_sigma[2],
            out[0],
            out[1],
            out[2]
        ),
        start_s: None,
        end_s: None,
        samples: 0,
        action: Action::Repaired,
    });
    Some(out)
}

/// Means on each side of an event fitted to tell a step from a disturbance.
pub(crate) const SIDE_MEANS: usize = 12;
/// A level shift across an event beyond this many of its 1σ is a step; within, the level comes
/// back: a disturbance.
pub(crate) const SHIFT_SIGMAS: f64 = 5.0;
/// A mean inside a disturbance departs from the fit by more than this many of its 1σ: excluded.
pub(crate) const DISTURBED_SIGMAS: f64 = 4.0;

/// A level shift and its 1σ (m/s²), and the means departing from the fit (index, residual).
type Shift = (f64, f64, Vec<(usize, f64)>);

/// The level shift across means `i0..=i1` of axis `a` and its 1σ, and the means in that span that
/// depart from the fit: a cubic in time (the slow gravity signal) plus a step at the event's
/// middle, fitted by weighted least squares (weights the means' counts) to up to
/// [`SIDE_MEANS`] means on each side; `sigma_full` is the 1σ of a full-window mean, `typical`
/// the record's [`typical_count`] (taken once: per position it was 15 % of a clean identify).
/// `None` when a side has fewer than 4 means (an event at the record's ends).
fn shift_across(
    means: &[Measurement],
    a: usize,
    i0: usize,
    i1: usize,
    sigma_full: f64,
    typical: f64,
) -> Option<Shift> {
    let before: Vec<usize> = (i0.saturating_sub(SIDE_MEANS)..i0).collect();
    let after: Vec<usize> = (i1 + 1..(i1 + 1 + SIDE_MEANS).min(means.len())).collect();
    if before.len() < 4 || after.len() < 4 {
        return None;
    }
    let tc = 0.5 * (means[i0].t_s + means[i1].t_s);
    let scale = (means[i1].t_s - means[i0].t_s).max(1.0) + 1.0;
    let row = |j: usize| {
        let u = (means[j].t_s - tc) / scale;
        [1.0, u, u * u, u * u * u, if u > 0.0 { 1.0 } else { 0.0 }]
    };
    let mut ata = nalgebra::SMatrix::<f64, 5, 5>::zeros();
    let mut atb = nalgebra::SVector::<f64, 5>::zeros();
    for &j in before.iter().chain(&after) {
        let r = nalgebra::SVector::<f64, 5>::from(row(j));
        let w = f64::from(means[j].count.max(1)) / typical;
        ata += w * r * r.transpose();
        atb += w * r * means[j].specific_force[a];
    }
    let inv = ata.try_inverse()?;
    let p = inv * atb;
    let shift = p[4];
    let shift_sigma = inv[(4, 4)].sqrt() * sigma_full;
    let disturbed = (i0..=i1)
        .filter_map(|j| {
            let fit = nalgebra::SVector::<f64, 5>::from(row(j)).dot(&p);
            let sd = sigma_full * (typical / f64::from(means[j].count.max(1))).sqrt();
            let r = means[j].specific_force[a] - fit;
            (r.abs() > DISTURBED_SIGMAS * sd).then_some((j, r))
        })
        .collect();
    Some((shift, shift_sigma, disturbed))
}

/// Longest disturbance, in filter periods, whose start and end (two events of opposite sign)
/// are joined into one: a bump or a door left open for up to an hour at the paper's 60 s.
pub(crate) const DISTURBANCE_MAX_MEANS: usize = 60;

/// One exceedance of the step check: means `i0..=i1`, the peak's difference.
struct Event {
    i0: usize,
    i1: usize,
    /// Index into the differences of the largest one.
    peak: usize,
}

/// The exceedances of the third differences `d` (robust 1σ `s`) beyond [`STEP_SIGMAS`], each
/// spanning consecutive exceedances; its peak is the middle of (J, −2J, J). `n` means in all.
fn events(d: &[Diff], s: f64, n: usize) -> Vec<Event> {
    let mut events = vec![];
    let mut k = 0;
    while k < d.len() {
        if d[k].z.abs() > STEP_SIGMAS * s {
            let start = k;
            while k < d.len() && d[k].k <= d[start].k + 4 && d[k].k - d[start].k <= 4 {
                k += 1;
            }
            let peak = (start..k)
                .max_by(|&i, &j| d[i].z.abs().total_cmp(&d[j].z.abs()))
                .unwrap_or(start);
            events.push(Event {
                i0: d[start].k,
                i1: (d[k - 1].k + 3).min(n - 1),
                peak,
            });
        } else {
            k += 1;
        }
    }
    events
}

/// The finding of a step on axis `a` at event `ev` (not repaired: named, with `--exclude`
/// suggested).
fn step_finding(means: &[Measurement], a: usize, d: &[Diff], ev: &Event, s: f64) -> Finding {
    let j = -d[ev.peak].raw / 2.0;
    let idx = (d[ev.peak].k + 2).min(means.len() - 1);
    let (t0, t1) = (means[ev.i0].t_s, means[ev.i1].t_s);
    Finding {
        kind: Kind::Step,
        message: format!(
            "axis {}: the filter-period means jump by about {j:+.2e} m/s^2 near t = {:.0} s ({:.0}× the noise of their third differences): \
             a bias step or a disturbance of the platform; not repaired (a disturbance you know of can be left out with --exclude {:.2}..T1, \
             hours, T1 where it ended: the run's end if it did not)",
            axis_name(a),
            means[idx].t_s,
            d[ev.peak].z.abs() / s,
            (t0 / 36.0).floor() / 100.0,
        ),
        start_s: Some(t0),
        end_s: Some(t1),
        samples: 0,
        action: Action::NotRepaired,
    }
}

/// Steps: third differences beyond [`STEP_SIGMAS`]; one finding per event. An event across which
/// the level comes back ([`shift_across`]) is a disturbance of the platform (a burst: a door
/// slammed, a bump), and so are two events of up to [`DISTURBANCE_MAX_MEANS`] apart across which
/// together it comes back (its start and its end): its means are excluded (returned, indices
/// into `means`, sorted) and the finding says so. One that leaves the level shifted is a `step`
/// (not repaired; the message suggests `--exclude`).
pub(crate) fn check_steps(
    means: &[Measurement],
    skip: &[bool; 3],
    findings: &mut Vec<Finding>,
) -> Vec<usize> {
    let mut excluded = vec![];
    for a in (0..3).filter(|&a| !skip[a]) {
        let d = third_differences(means, a);
        if d.len() < 30 {
            continue;
        }
        let s = sigma_of_z(&d);
        if s <= 0.0 {
            continue;
        }
        let events = events(&d, s, means.len());
        let sigma_full = s / 20f64.sqrt();
        let typical = typical_count(means);
        let burst = |i0: usize, i1: usize| {
            shift_across(means, a, i0, i1, sigma_full, typical)
                .filter(|(shift, sd, dist)| shift.abs() <= SHIFT_SIGMAS * sd && !dist.is_empty())
        };
        let mut e = 0;
        while e < events.len() {
            let ev = &events[e];
            // The event alone, or with a later one (its end) within the longest disturbance.
            let found = std::iter::once(e)
                .chain(
                    (e + 1..events.len())
                        .take_while(|&f| events[f].i0 <= ev.i1 + DISTURBANCE_MAX_MEANS),
                )
                .find_map(|f| burst(ev.i0, events[f].i1).map(|b| (f, b)));
            if let Some((last, (shift, sd, dist))) = found {
                let (w0, w1) = (means[dist[0].0].t_s, means[dist[dist.len() - 1].0].t_s);
                let samples = dist.iter().map(|&(i, _)| means[i].count as usize).sum();
                let worst = dist
                    .iter()
                    .map(|x| x.1)
                    .max_by(|x, y| x.abs().total_cmp(&y.abs()))
                    .unwrap_or(0.0);
                findings.push(Finding {
                    kind: Kind::Disturbance,
                    message: format!(
                        "axis {}: a burst at t = {w0:.0}–{w1:.0} s ({:.3}–{:.3} h): {} filter-period mean(s) depart from the slow signal by up to {worst:+.2e} m/s^2 \
                         ({:.0}× the noise of their third differences) and the level comes back (shift across it {shift:+.1e} ± {sd:.1e} m/s^2: not a step): \
                         a disturbance of the platform; those filter periods are excluded",
                        axis_name(a),
                        w0 / 3600.0,
                        w1 / 3600.0,
                        dist.len(),
                        d[ev.peak].z.abs() / s,
                    ),
                    start_s: Some(w0),
                    end_s: Some(w1),
                    samples,
                    action: Action::Rejected,
                });
                excluded.extend(dist.iter().map(|x| x.0));
                e = last + 1;
                continue;
            }
            findings.push(step_finding(means, a, &d, ev, s));
            e += 1;
        }
    }
    excluded.sort_unstable();
    excluded.dedup();
    excluded
}

/// A local level shift beyond this many of its 1σ, anywhere in the run, is a bias step
/// ([`find_bias_steps`]). Positions tried: one per filter period and axis (~10 800 on 60 h at
/// 60 s, correlated over the ~25 means of one fit); at 6σ the chance of one false step per run
/// is below 1e-5 for white Gaussian means.
pub(crate) const BIAS_STEP_SIGMAS: f64 = 6.0;
/// The local fit's shift must exceed this many of its 1σ before the long fit sizes it.
pub(crate) const PRESCREEN_SIGMAS: f64 = 1.5;
/// Largest number of bias steps repaired per axis.
pub(crate) const MAX_BIAS_STEPS: usize = 3;

/// A bias step of an accelerometer axis found in the filter-period means.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BiasStep {
    /// Axis, 0..3.
    pub axis: usize,
    /// Size, m/s² (the later readings are this much higher).
    pub size: f64,
    /// Its 1σ, m/s².
    pub sigma: f64,
    /// Index of the mean whose window holds the jump (excluded: part before, part after).
    pub at: usize,
    /// Estimated time of the jump, s (from how much of it the transitional mean holds).
    pub t_s: f64,
}

/// Bias steps too small for the third differences (≥ 8σ of a difference, ~18σ of a mean): at each
/// mean in turn, the level shift across it ([`shift_across`]: a cubic in time for the slow
/// gravity signal plus a step, fitted to [`SIDE_MEANS`] means on each side) over its 1σ; the
/// largest beyond [`BIAS_STEP_SIGMAS`] is a step, removed from the means, and the search
/// repeated (at most [`MAX_BIAS_STEPS`] per axis); more than one in the run is no step (slow
/// structure, e.g. a Gauss–Markov drift: none is returned). `sigma_full` is the 1σ of a full-window mean
/// per axis (the means' own scatter).
pub(crate) fn find_bias_steps(
    means: &[Measurement],
    skip: &[bool; 3],
    sigma_full: &[f64; 3],
) -> Vec<BiasStep> {
    let mut out = vec![];
    let typical = typical_count(means);
    for a in (0..3).filter(|&a| !skip[a] && sigma_full[a] > 0.0) {
        let mut x: Vec<Measurement> = means.to_vec();
        // The typical spacing of the means: a fit whose sides span a gap (an excluded stretch,
        // a gap in the recording) is not tried, the slow signal is no cubic across hours.
        let mut gaps: Vec<f64> = x.windows(2).map(|w| w[1].t_s - w[0].t_s).collect();
        if gaps.is_empty() {
            continue;
        }
        let h = robust::median(&mut gaps);
        let span = (2 * SIDE_MEANS + 2) as f64 * h;
        for _ in 0..MAX_BIAS_STEPS {
            // Sized on hours of signal ([`refine_step`]) where the local fit (cubic + step, 12
            // means each side) shows any shift (beyond PRESCREEN_SIGMAS: ~13 % of positions on
            // a clean run, so the long fit runs where it may matter); the long fit must agree
            // with the local one (next to another feature, e.g. a larger step a few means
            // away that bends the local cubic, or near the run's ends, where no hours of means
            // size it, there is no repair: the third differences name a large one a `step`).
            let done: Vec<usize> = out
                .iter()
                .filter(|b: &&BiasStep| b.axis == a)
                .map(|b| b.at)
                .collect();
            // The positions are tried on all cores (a 60-h run at 1 s: 25 ms on one) and the
            // best taken in their order, as one core would.
            let tried: Vec<(usize, f64, f64)> = (SIDE_MEANS..x.len().saturating_sub(SIDE_MEANS))
                .into_par_iter()
                .filter(|&c| x[c + SIDE_MEANS].t_s - x[c - SIDE_MEANS].t_s <= span)
                .map_init(RefineRows::default, |rows, c| {
                    let (shift, sd, _) = shift_across(&x, a, c, c, sigma_full[a], typical)?;
                    if !(sd > 0.0 && (shift / sd).abs() > PRESCREEN_SIGMAS) {
                        return None;
                    }
                    let (size_h, sd_h) =
                        refine_step(&x, a, c, &done, (sigma_full[a], typical), rows)?;
                    ((size_h - shift).abs() <= BIAS_STEP_SIGMAS * sd && sd_h > 0.0)
                        .then_some((c, size_h, sd_h))
                })
                .flatten()
                .collect();
            let best = tried
                .into_iter()
                .max_by(|p, q| (p.1 / p.2).abs().total_cmp(&(q.1 / q.2).abs()));
            let Some((c, size, sd)) = best else { break };
            if (size / sd).abs() <= BIAS_STEP_SIGMAS {
                break;
            }
            // How much of the jump the transitional mean holds: its departure from the level
            // before (the fit without the step, evaluated there) over the size.
            let before = (c.saturating_sub(SIDE_MEANS)..c).collect::<Vec<_>>();
            let level_before = local_fit(&x, a, &before, x[c].t_s);
            let half = if c + 1 < x.len() {
                0.5 * (x[c + 1].t_s - x[c].t_s)
            } else {
                0.5 * (x[c].t_s - x[c - 1].t_s)
            };
            // The window spans ~[t − half, t + half]; a fraction f after the jump.
            let f = ((x[c].specific_force[a] - level_before) / size).clamp(0.0, 1.0);
            let t_s = x[c].t_s + half - 2.0 * half * f;
            out.push(BiasStep {
                axis: a,
                size,
                sigma: sd,
                at: c,
                t_s,
            });
            for m in &mut x[c + 1..] {
                m.specific_force[a] -= size;
            }
            // The transitional mean is left out of later searches' fits: set to the fit.
            x[c].specific_force[a] = level_before;
        }
    }
    // One step is a fault; several (on one axis or across axes) are slow structure the
    // Earth-rate basis does not follow — a Gauss–Markov drift wandering the platform gave 3 per
    // axis on every axis (9 per run, seeds 1–3, σ 0.01–0.05 deg/h, τ 2–5 h) — which the model
    // ladder must name (`drift-markov`), not a repair of the data.
    if out.len() > 1 {
        return vec![];
    }
    out
}

/// A cubic in time fitted to means `idx` of axis `a` (weights their counts), evaluated at `t`.
fn local_fit(means: &[Measurement], a: usize, idx: &[usize], t: f64) -> f64 {
    if idx.len() < 4 {
        return idx.iter().map(|&j| means[j].specific_force[a]).sum::<f64>()
            / idx.len().max(1) as f64;
    }
    let scale = (means[idx[idx.len() - 1]].t_s - means[idx[0]].t_s).max(1.0);
    let row = |tt: f64| {
        let u = (tt - t) / scale;
        nalgebra::SVector::<f64, 4>::new(1.0, u, u * u, u * u * u)
    };
    let mut ata = nalgebra::SMatrix::<f64, 4, 4>::zeros();
    let mut atb = nalgebra::SVector::<f64, 4>::zeros();
    for &j in idx {
        let r = row(means[j].t_s);
        let w = f64::from(means[j].count.max(1));
        ata += w * r * r.transpose();
        atb += w * r * means[j].specific_force[a];
    }
    match ata.try_inverse() {
        Some(inv) => (inv * atb)[0],
        None => means[idx[idx.len() - 1]].specific_force[a],
    }
}

/// Half-width of the fit that sizes a found bias step, s: ±6 h. On 60 h at 1 s, ±3 h sized a
/// step to 3.9e-5 m/s² (1σ), ±6 h to 3.1e-5, and found one of 2.5e-4 in 17 of 20 seeds, not 10.
pub(crate) const REFINE_HALF_S: f64 = 6.0 * 3600.0;

/// The means refine_step fits about the candidate mean `c`: contiguous ones within
/// `REFINE_HALF_S` on each side (a gap of more than 3 spacings ends a side), earlier side first
/// (from `c` outwards), without the `other` candidates.
fn refine_window(means: &[Measurement], c: usize, other: &[usize]) -> Vec<usize> {
    let tc = means[c].t_s;
    let h = if c + 1 < means.len() {
        means[c + 1].t_s - means[c].t_s
    } else {
        means[c].t_s - means[c - 1].t_s
    };
    let mut idx = vec![];
    let mut j = c;
    while j > 0
        && tc - means[j - 1].t_s <= REFINE_HALF_S
        && means[j].t_s - means[j - 1].t_s <= 3.0 * h
    {
        j -= 1;
        idx.push(j);
    }
    let mut j = c;
    while j + 1 < means.len()
        && means[j + 1].t_s - tc <= REFINE_HALF_S
        && means[j + 1].t_s - means[j].t_s <= 3.0 * h
    {
        j += 1;
        idx.push(j);
    }
    idx.retain(|j| !other.contains(j));
    idx
}

/// The size of a bias step at mean `c` of axis `a` and its 1σ, from the means within
/// [`REFINE_HALF_S`] of it (not across a gap), the transitional mean and those of `other`
/// steps' windows left out. A space-stable platform sees gravity turn at the Earth's rate: each
/// axis is a + b·cos Ωt + c·sin Ωt, modulated slowly as the drift turns the platform, so
/// {1, cos Ωτ, sin Ωτ} × {1, u, u², u³} (τ from the step, u = τ/half-width) plus the step fits
/// hours of signal to far below the noise: the local cubic's 1σ (~1.3σ of a mean) would leave
/// the later half of the run offset by a bias the model then reads as a misfit.
///
/// Over ±6 h (a quarter turn) the 12 slow functions are close to dependent (the design's
/// condition number is ~7e9), and the normal equations solved in doubles regularise them by
/// their rounding: on a 60-h run at 60 s the size came out up to 0.63σ from an SVD's least
/// squares, its 1σ 8 % below the exact one (50-digit arithmetic, at 15 h). The screening's
/// thresholds were calibrated on these numbers, and they are fragile: the same normal equations
/// summed as moments (2× faster) found a 9σ step in a clean 60-h log at 55 s
/// (`slow_logs_give_no_finding`). A well-posed basis would need calibrating anew.
pub(crate) fn refine_step(
    means: &[Measurement],
    a: usize,
    c: usize,
    other: &[usize],
    (sigma_full, typical): (f64, f64),
    rows: &mut RefineRows,
) -> Option<(f64, f64)> {
    let tc = means[c].t_s;
    let idx = refine_window(means, c, other);
    let (nb, na) = (
        idx.iter().filter(|&&j| j < c).count(),
        idx.iter().filter(|&&j| j > c).count(),
    );
    // Both sides must hold their ±6 h: an asymmetric fit extrapolates the 12 slow functions
    // past one side's end (a clean 60-h run then showed "steps" of 2e-4 at 1.3 h and 58 h in
    // 21 of 100 seeds).
    let reach = |j: Option<&usize>| j.map_or(0.0, |&j| (means[j].t_s - tc).abs());
    let first_after = idx.iter().position(|&j| j > c);
    let (before_end, after_end) = match first_after {
        Some(k) if k > 0 => (reach(idx[..k].last()), reach(idx.last())),
        _ => return None,
    };
    if nb < 2 * REFINE_N
        || na < 2 * REFINE_N
        || before_end < 0.95 * REFINE_HALF_S
        || after_end < 0.95 * REFINE_HALF_S
    {
        return None;
    }
    let window = Window {
        means,
        c,
        idx: &idx,
        typical,
    };
    let inv = rows.design_inverse(&window)?;
    // AᵀWb summed as (w·rᵢ)·b, as nalgebra's `w * r * b` did.
    let mut atb = nalgebra::SVector::<f64, REFINE_N>::zeros();
    for &j in &idx {
        let (tau, w) = window.tau_weight(j);
        for (x, ri) in atb.iter_mut().zip(rows.row(j as isize - c as isize, tau)) {
            *x += w * ri * means[j].specific_force[a];
        }
    }
    let p = inv * atb;
    Some((p[12], inv[(12, 12)].sqrt() * sigma_full))
}

/// The means [`refine_step`] fits about the candidate `c`: `idx` ([`refine_window`]), weighed
/// by their counts over the `typical` one.
struct Window<'a> {
    means: &'a [Measurement],
    c: usize,
    idx: &'a [usize],
    typical: f64,
}

impl Window<'_> {
    /// τ of mean `j` from the candidate, s, and its weight.
    fn tau_weight(&self, j: usize) -> (f64, f64) {
        let m = &self.means[j];
        (
            m.t_s - self.means[self.c].t_s,
            f64::from(m.count.max(1)) / self.typical,
        )
    }

    /// AᵀWA (columns), on the AVX2 build where the CPU has it (the same bits).
    fn design(&self, rows: &mut RefineRows) -> [[f64; REFINE_N]; REFINE_N] {
        #[cfg(target_arch = "x86_64")]
        if estimator_core::cpu::has_avx2() {
            // SAFETY: `design_avx2` needs AVX2, which the CPU was just found to have.
            return unsafe { self.design_avx2(rows) };
        }
        self.design_body(rows)
    }

    /// [`Window::design`] compiled for AVX2 ([`estimator_core::cpu`]): no fused multiply-add,
    /// so the same bits (a design summed afresh: 53 → 38 ms of the search of a clean 60-h run
    /// at 1 s).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn design_avx2(&self, rows: &mut RefineRows) -> [[f64; REFINE_N]; REFINE_N] {
        self.design_body(rows)
    }

    /// [`Window::design`]: element (i, k) summed as (w·rᵢ)·rₖ, a rank-one update written out
    /// (nalgebra's `w * r * r.transpose()` makes the same products and sums, through a 13 × 13
    /// temporary that took half the search's time).
    #[inline(always)]
    fn design_body(&self, rows: &mut RefineRows) -> [[f64; REFINE_N]; REFINE_N] {
        let mut ata = [[0.0; REFINE_N]; REFINE_N];
        for &j in self.idx {
            let (tau, w) = self.tau_weight(j);
            let r = rows.row(j as isize - self.c as isize, tau);
            let wr: [f64; REFINE_N] = std::array::from_fn(|i| w * r[i]);
            for (col, rk) in ata.iter_mut().zip(r) {
                for (x, wri) in col.iter_mut().zip(&wr) {
                    *x += wri * rk;
                }
            }
        }
        ata
    }
}

/// The functions [`refine_step`] fits: {1, cos Ωτ, sin Ωτ} × {1, u, u², u³} and the step.
const REFINE_N: usize = 13;

/// What [`refine_step`] reuses from one candidate to the next, bit for bit what it would make
/// afresh. One per worker of the search (`map_init`).
///
/// - The rows by their offset from the candidate mean, each kept with the τ it was made for and
///   made anew where τ differs: on the even grid of a recording's means the same offset is the
///   same τ for every candidate, and the ±6 h of sines and cosines each candidate made afresh
///   were a quarter of the search's time.
/// - The design's inverse (AᵀWA)⁻¹, kept with the τ and weight of each of its means: on that
///   grid it is the same for every candidate away from the run's ends, a gap or a step already
///   found, and summing it was 13 times the work of the data's side, AᵀWb.
#[derive(Default)]
pub(crate) struct RefineRows {
    before: Vec<Option<(f64, [f64; REFINE_N])>>,
    after: Vec<Option<(f64, [f64; REFINE_N])>>,
    /// The (τ, weight) bits of the last design's means, in order, and its inverse.
    design: (
        Vec<(u64, u64)>,
        Option<nalgebra::SMatrix<f64, REFINE_N, REFINE_N>>,
    ),
    /// The candidate's (τ, weight) bits, compared with `design`'s.
    key: Vec<(u64, u64)>,
}

impl RefineRows {
    /// (AᵀWA)⁻¹ of `window` ([`Window::design`]); `None` where singular.
    fn design_inverse(
        &mut self,
        window: &Window<'_>,
    ) -> Option<nalgebra::SMatrix<f64, REFINE_N, REFINE_N>> {
        self.key.clear();
        self.key.extend(window.idx.iter().map(|&j| {
            let (tau, w) = window.tau_weight(j);
            (tau.to_bits(), w.to_bits())
        }));
        if self.key != self.design.0 {
            let ata: nalgebra::SMatrix<f64, REFINE_N, REFINE_N> =
                nalgebra::SMatrix::from(window.design(self));
            self.design.1 = ata.try_inverse();
            std::mem::swap(&mut self.design.0, &mut self.key);
        }
        self.design.1
    }

    /// The row of the mean `offset` means from the candidate, `tau` seconds from it.
    fn row(&mut self, offset: isize, tau: f64) -> [f64; REFINE_N] {
        let (side, k) = if offset < 0 {
            (&mut self.before, offset.unsigned_abs())
        } else {
            (&mut self.after, offset.unsigned_abs())
        };
        if side.len() <= k {
            side.resize(k + 1, None);
        }
        match side[k] {
            Some((t, r)) if t.to_bits() == tau.to_bits() => r,
            _ => {
                let r = refine_row(tau);
                side[k] = Some((tau, r));
                r
            }
        }
    }
}

/// One row of [`refine_step`]'s fit at `tau` seconds from the candidate (u = τ / half-width).
fn refine_row(tau: f64) -> [f64; REFINE_N] {
    let u = tau / REFINE_HALF_S;
    let (s, co) = (estimator_core::units::EARTH_RATE_RADPS * tau).sin_cos();
    let mut r = [0.0; REFINE_N];
    let mut k = 0;
    for p in [1.0, u, u * u, u * u * u] {
        for f in [1.0, co, s] {
            r[k] = p * f;
            k += 1;
        }
    }
    r[12] = if tau > 0.0 { 1.0 } else { 0.0 };
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fit as it was written before [`RefineRows`]: each row made afresh, the normal
    /// equations summed by nalgebra's rank-one update.
    fn refine_step_afresh(
        means: &[Measurement],
        a: usize,
        c: usize,
        other: &[usize],
        (sigma_full, typical): (f64, f64),
    ) -> Option<(f64, f64)> {
        let tc = means[c].t_s;
        let mut ata = nalgebra::SMatrix::<f64, REFINE_N, REFINE_N>::zeros();
        let mut atb = nalgebra::SVector::<f64, REFINE_N>::zeros();
        for j in refine_window(means, c, other) {
            let r = nalgebra::SVector::<f64, REFINE_N>::from(refine_row(means[j].t_s - tc));
            let w = f64::from(means[j].count.max(1)) / typical;
            ata += w * r * r.transpose();
            atb += w * r * means[j].specific_force[a];
        }
        let inv = ata.try_inverse()?;
        let p = inv * atb;
        Some((p[12], inv[(12, 12)].sqrt() * sigma_full))
    }

    /// Minute means of 30 h with a gravity-like signal, noise, a step at 15 h, and an uneven
    /// stretch (a shorter mean, then the grid shifted by 7 s) so that one offset meets two τ.
    fn means() -> Vec<Measurement> {
        let mut rng = 0x2545_f491_4f6c_dd1d_u64;
        let mut noise = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        (0..1800)
            .map(|k| {
                let t_s = 30.0 + 60.0 * k as f64 + if k > 1000 { 7.0 } else { 0.0 };
                let w = estimator_core::units::EARTH_RATE_RADPS * t_s;
                let step = if t_s > 15.0 * 3600.0 { 3e-5 } else { 0.0 };
                let f = 0.1 * w.cos() + 0.05 * w.sin() + step + 1e-5 * noise();
                Measurement {
                    t_s,
                    specific_force: [f, -f, 9.8],
                    temp_c: f64::NAN,
                    count: if k == 1000 { 40 } else { 60 },
                    variance: [1e-10; 3],
                    time_var_s2: 300.0,
                }
            })
            .collect()
    }

    /// Rows and designs reused across candidates give the fit made afresh bit for bit — on the
    /// even grid, where every row and the design are reused; across the shifted stretch and
    /// the short mean, where an offset's τ or a weight changes; and where a step found before
    /// (`other`) leaves a mean out. A row or design reused where it differs, or the normal
    /// equations summed transposed, changes the bits.
    #[test]
    fn rows_reused_across_candidates_give_the_fit_made_afresh() {
        let means = means();
        let mut rows = RefineRows::default();
        let mut sized = 0;
        for c in (360..1440).step_by(7) {
            let other: &[usize] = if c % 3 == 0 { &[c - 200] } else { &[] };
            let reused = refine_step(&means, 0, c, other, (1e-5, 60.0), &mut rows);
            let afresh = refine_step_afresh(&means, 0, c, other, (1e-5, 60.0));
            let bits = |r: Option<(f64, f64)>| r.map(|(s, d)| (s.to_bits(), d.to_bits()));
            assert_eq!(bits(reused), bits(afresh), "candidate {c}");
            sized += usize::from(reused.is_some());
        }
        assert!(sized > 100, "only {sized} candidates were sized");
    }
}
