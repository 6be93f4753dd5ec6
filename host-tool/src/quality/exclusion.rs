//! Stretches left out before the screening: a sensor pinned at a rail (saturation), and the
//! windows the user excludes (`--exclude T0..T1`).
//!
//! **Saturation.** A sensor or its converter that cannot read beyond a rail returns the rail
//! itself: the axis' extreme value (its largest or its smallest reading) repeats, bit for bit,
//! while the signal lies beyond it (a flat top). Real-valued noisy outputs never repeat a
//! value; so on an axis whose other readings do not repeat either (undithered rounding, where
//! the extremes dwell on one level by nature, is the `quantization` finding's), an extreme held
//! by at least [`SAT_MIN_SAMPLES`] readings, [`SAT_PILE_FACTOR`] times as many as any other
//! value, that the signal reaches continuously (the readings beside a pinned run lie within
//! [`SAT_NEAR_SIGMAS`] raw 1σ of the rail, unlike a channel stuck at an arbitrary value: that is
//! `stuck`), is a rail. The readings next to the pinned ones are cut by the rail too (their
//! noise is clipped, their mean biased), so the whole filter periods around the pinned stretch
//! are excluded, not only the pinned readings.

use std::collections::HashMap;

use estimator_core::robust;
use estimator_core::Sample;

use super::{axis_name, Action, Finding, Kind};

/// Fewest readings at an extreme that can be a rail.
pub(crate) const SAT_MIN_SAMPLES: usize = 5;
/// The rail holds at least this many times as many readings as any other value.
pub(crate) const SAT_PILE_FACTOR: usize = 3;
/// The readings beside a pinned run lie within this many raw 1σ of the rail.
pub(crate) const SAT_NEAR_SIGMAS: f64 = 10.0;
/// Pinned readings closer than this many filter periods form one stretch.
pub(crate) const SAT_JOIN_PERIODS: f64 = 2.0;

/// One excluded stretch, [t0, t1) in the recording's time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Stretch {
    /// Start, s.
    pub t0: f64,
    /// End (exclusive), s.
    pub t1: f64,
}

/// The samples left after the exclusions (`None`: all of them), and the findings.
pub(crate) fn exclude(
    samples: &[Sample],
    period_s: f64,
    user_s: &[(f64, f64)],
) -> (Option<Vec<Sample>>, Vec<Finding>) {
    let mut findings = vec![];
    let mut drop: Vec<Stretch> = vec![];
    for &(a, b) in user_s {
        findings.push(excluded_as_asked(samples, a, b));
        drop.push(Stretch {
            t0: a,
            t1: b.next_up(),
        });
    }
    for (axis, rail, stretches, pinned) in saturated(samples, period_s) {
        findings.extend(saturation_findings(samples, axis, rail, &stretches, pinned));
        drop.extend(stretches);
    }
    if drop.is_empty() {
        return (None, findings);
    }
    let kept = samples
        .iter()
        .filter(|s| !drop.iter().any(|d| s.t_s >= d.t0 && s.t_s < d.t1))
        .copied()
        .collect();
    (Some(kept), findings)
}

/// The finding for a window [a, b] s excluded by `--exclude`, with the samples it leaves out.
fn excluded_as_asked(samples: &[Sample], a: f64, b: f64) -> Finding {
    let n = samples.iter().filter(|s| s.t_s >= a && s.t_s <= b).count();
    Finding {
        kind: Kind::Excluded,
        message: format!(
            "t = {:.4}–{:.4} h excluded as asked (--exclude): {n} samples left out{}",
            a / 3600.0,
            b / 3600.0,
            if n == 0 {
                " (no sample lies in that window)"
            } else {
                ""
            }
        ),
        start_s: Some(a),
        end_s: Some(b),
        samples: n,
        action: Action::Rejected,
    }
}

/// The findings for the stretches excluded at `axis`'s rail `rail`, m/s² (`pinned` readings at
/// it): one per stretch for the first ten, one for the rest.
fn saturation_findings(
    samples: &[Sample],
    axis: usize,
    rail: f64,
    stretches: &[Stretch],
    pinned: usize,
) -> Vec<Finding> {
    let mut findings = vec![];
    let shown = stretches.len().min(10);
    for (i, st) in stretches.iter().enumerate() {
        let n = samples
            .iter()
            .filter(|s| s.t_s >= st.t0 && s.t_s < st.t1)
            .count();
        if i == shown {
            let rest: Vec<String> = stretches[shown..]
                .iter()
                .map(|s| format!("{:.3}–{:.3} h", s.t0 / 3600.0, s.t1 / 3600.0))
                .collect();
            findings.push(Finding {
                kind: Kind::Saturated,
                message: format!(
                    "axis {}: {} more stretches at the rail {rail:+} m/s^2 excluded ({})",
                    axis_name(axis),
                    stretches.len() - shown,
                    rest.join(", ")
                ),
                start_s: Some(st.t0),
                end_s: stretches.last().map(|s| s.t1),
                samples: 0,
                action: Action::Rejected,
            });
            break;
        }
        findings.push(Finding {
            kind: Kind::Saturated,
            message: format!(
                "axis {} is pinned at its rail {rail:+} m/s^2 ({} reading): {pinned} readings in the run repeat that extreme value exactly \
                 (a flat top: the sensor or its converter cannot read beyond it); the filter periods of t = {:.3}–{:.3} h ({n} samples) are excluded",
                axis_name(axis),
                if rail > 0.0 { "its largest" } else { "its smallest" },
                st.t0 / 3600.0,
                st.t1 / 3600.0
            ),
            start_s: Some(st.t0),
            end_s: Some(st.t1),
            samples: n,
            action: Action::Rejected,
        });
    }
    findings
}

/// Rails found: (axis, rail value, stretches excluded, readings pinned at it).
pub(crate) fn saturated(
    samples: &[Sample],
    period_s: f64,
) -> Vec<(usize, f64, Vec<Stretch>, usize)> {
    let mut out = vec![];
    let (hi, lo) = extremes(samples);
    // The readings at each axis' extremes, all axes in one pass (the run is read once, not six
    // times: ~4 ms of a 60-h run at 1 s).
    let mut pinned = [[0usize; 2]; 3];
    for s in samples {
        for a in 0..3 {
            let x = s.specific_force[a];
            pinned[a][0] += usize::from(x == hi[a]);
            pinned[a][1] += usize::from(x == lo[a]);
        }
    }
    for a in 0..3 {
        // No finite reading (hi = −∞), or a dead axis (its own finding).
        if hi[a] <= lo[a] || !hi[a].is_finite() {
            continue;
        }
        for (rail, pinned) in [(hi[a], pinned[a][0]), (lo[a], pinned[a][1])] {
            if pinned < SAT_MIN_SAMPLES || !is_rail(samples, a, rail, [hi[a], lo[a]], pinned) {
                continue;
            }
            out.push((a, rail, stretches(samples, a, rail, period_s), pinned));
        }
    }
    out
}

/// Each axis' largest and smallest finite reading (−∞ and +∞ where it has none).
fn extremes(samples: &[Sample]) -> ([f64; 3], [f64; 3]) {
    let (mut hi, mut lo) = ([f64::NEG_INFINITY; 3], [f64::INFINITY; 3]);
    for s in samples {
        for a in 0..3 {
            let x = s.specific_force[a];
            if x.is_finite() {
                hi[a] = hi[a].max(x);
                lo[a] = lo[a].min(x);
            }
        }
    }
    (hi, lo)
}

/// The tests of the module's doc on a candidate rail held by `pinned` readings; `extremes` are
/// the axis' largest and smallest readings (a sensor clipped at both rails: neither counts
/// among the other readings of the other).
fn is_rail(samples: &[Sample], a: usize, rail: f64, extremes: [f64; 2], pinned: usize) -> bool {
    let v = |k: usize| samples[k].specific_force[a];
    let other = |k: usize| !extremes.contains(&v(k));
    // The other readings: how often they repeat (undithered rounding: not tested), and the
    // most common one.
    let (mut steps, mut repeats) = (0usize, 0usize);
    for k in 1..samples.len() {
        if other(k) && other(k - 1) {
            steps += 1;
            repeats += usize::from(v(k) == v(k - 1));
        }
    }
    if steps == 0 || repeats as f64 > super::UNDITHERED_REPEAT_RATE * steps as f64 {
        return false;
    }
    let mut counts: HashMap<u64, usize> = HashMap::new();
    for k in 0..samples.len() {
        if other(k) && v(k).is_finite() {
            *counts.entry(v(k).to_bits()).or_default() += 1;
        }
    }
    let most = counts.values().copied().max().unwrap_or(0);
    if pinned < SAT_PILE_FACTOR * most.max(1) {
        return false;
    }
    // Raw 1σ from consecutive differences of the other readings (median |Δ|·1.4826/√2), at
    // least the output step.
    let mut d: Vec<f64> = (1..samples.len())
        .filter(|&k| other(k) && other(k - 1))
        .map(|k| (v(k) - v(k - 1)).abs())
        .filter(|x| x.is_finite())
        .collect();
    if d.is_empty() {
        return false;
    }
    let step = d
        .iter()
        .copied()
        .filter(|x| *x > 0.0)
        .fold(f64::INFINITY, f64::min);
    let sigma = (robust::sigma_from_abs(&mut d) / 2f64.sqrt()).max(if step.is_finite() {
        step
    } else {
        0.0
    });
    // Beside each pinned run: the reading just before and just after.
    let (mut near, mut far) = (0usize, 0usize);
    let mut k = 0;
    while k < samples.len() {
        if v(k) != rail {
            k += 1;
            continue;
        }
        let start = k;
        while k < samples.len() && v(k) == rail {
            k += 1;
        }
        for j in [start.checked_sub(1), (k < samples.len()).then_some(k)]
            .into_iter()
            .flatten()
        {
            if (v(j) - rail).abs() <= SAT_NEAR_SIGMAS * sigma {
                near += 1;
            } else {
                far += 1;
            }
        }
    }
    near > far
}

/// The filter periods holding the pinned readings, joined when closer than
/// [`SAT_JOIN_PERIODS`].
fn stretches(samples: &[Sample], a: usize, rail: f64, period_s: f64) -> Vec<Stretch> {
    let p = period_s.max(1e-9);
    let mut out: Vec<Stretch> = vec![];
    for s in samples.iter().filter(|s| s.specific_force[a] == rail) {
        let w0 = (s.t_s / p).floor() * p;
        match out.last_mut() {
            Some(last) if s.t_s - last.t1 <= (SAT_JOIN_PERIODS - 1.0) * p => {
                last.t1 = last.t1.max(w0 + p);
            }
            _ => out.push(Stretch { t0: w0, t1: w0 + p }),
        }
    }
    out
}
