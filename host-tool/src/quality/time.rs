//! The time axis against the Earth: on a static base gravity turns in the space-stable platform
//! frame at the Earth's rate about the Earth's axis, so the angle it sweeps between two samples
//! fixes how many seconds lie between them. A time column in ms (or minutes, hours) shows up as a
//! sweep rate 1000× (1/60×, 1/3600×) off; gaps and a change of sample rate are noted.

use estimator_core::robust::median;
use estimator_core::units::EARTH_RATE_RADPS;
use estimator_core::{Sample, Site};
use nalgebra::Vector3;
use std::borrow::Cow;

use super::physics::Refuse;
use super::{Action, Finding, Kind};

/// The measured sweep may differ from the Earth-rate prediction by this factor (drift of a few
/// deg/h against 15 cos(L) deg/h, a latitude a few degrees off) before the time unit is doubted.
pub(crate) const RATE_TOLERANCE: f64 = 1.35;
/// Time units recognised, as the factor from the file's unit to seconds.
pub(crate) const UNITS: [(f64, &str); 4] = [
    (1e-3, "milliseconds"),
    (1e-6, "microseconds"),
    (60.0, "minutes"),
    (3600.0, "hours"),
];
/// Smallest swept angle that tests the unit, rad (1°; noise of a block mean is ~1e-5 rad).
pub(crate) const MIN_SWEEP_RAD: f64 = 0.0175;

/// A sweep this much narrower than its widest so far has turned back, rad (0.2°; a block mean's
/// direction is good to ~1e-5 rad).
pub(crate) const TURN_BACK_RAD: f64 = 0.0035;

/// Ratio of the time elapsed according to the Earth's rotation to the file's time difference,
/// from ≤ 200 block means; `None` when the run sweeps too little (short, or near a pole).
pub fn time_scale(site: &Site, samples: &[Sample]) -> Option<f64> {
    let cos2 = site.latitude_rad.cos().powi(2);
    if samples.len() < 8 || cos2 < 0.05 {
        return None;
    }
    let blocks = 200.min(samples.len() / 4).max(2);
    let per = samples.len() / blocks;
    let mean = |k: usize| {
        let chunk = &samples[k * per..(k + 1) * per];
        let a = chunk.iter().fold(Vector3::zeros(), |acc, s| {
            acc + Vector3::from(s.specific_force)
        });
        let t = chunk.iter().map(|s| s.t_s).sum::<f64>() / chunk.len() as f64;
        (t, a.normalize())
    };
    let (t0, u0) = mean(0);
    let mut scales = vec![];
    let mut widest = 0.0f64;
    for k in 1..blocks {
        let (t, u) = mean(k);
        let angle = u0.cross(&u).norm().atan2(u0.dot(&u));
        // Past the widest point of the cone the chord turns back. At a high latitude the drift
        // (g-sensitive terms of ~1 deg/h against 15·cos L deg/h) narrows the cone, so the sweep
        // may turn back before Ωτ reaches 2.5 by the formula: a shrinking chord read as Ωτ < π
        // would give a rate far too low (a clean 54-h run at 68° N read 0.43: refused).
        widest = widest.max(angle);
        if angle < widest - TURN_BACK_RAD {
            break;
        }
        if angle < MIN_SWEEP_RAD {
            continue;
        }
        // On the cone: cos(angle) = 1 − cos²L·(1 − cos Ωτ).
        let c = 1.0 - (1.0 - angle.cos()) / cos2;
        if !(-1.0..=1.0).contains(&c) {
            continue;
        }
        let omega_tau = c.acos();
        if omega_tau > 2.5 {
            break; // past the point where the chord turns back
        }
        scales.push(omega_tau / EARTH_RATE_RADPS / (t - t0));
    }
    if scales.len() < 3 {
        return None;
    }
    Some(median(&mut scales))
}

/// Checks the time unit against the Earth's rotation and repairs a recognised one; returns the
/// factor applied to the file's times (1 when they are seconds).
pub(crate) fn check_units(
    site: &Site,
    samples: &mut Cow<'_, [Sample]>,
    findings: &mut Vec<Finding>,
) -> Result<f64, Refuse> {
    let mut applied = 1.0;
    if let Some(s) = time_scale(site, samples) {
        if !(1.0 / RATE_TOLERANCE..=RATE_TOLERANCE).contains(&s) {
            let unit = UNITS
                .iter()
                .find(|(f, _)| (1.0 / RATE_TOLERANCE..=RATE_TOLERANCE).contains(&(s / f)));
            match unit {
                Some(&(factor, name)) => {
                    for x in samples.to_mut().iter_mut() {
                        x.t_s *= factor;
                    }
                    applied = factor;
                    findings.push(Finding {
                        kind: Kind::TimeUnits,
                        message: format!(
                            "gravity turns {:.4}× as fast per time unit as the Earth's rotation predicts at latitude {:.2} deg: \
                             the time column is in {name}; converted to seconds",
                            1.0 / s,
                            site.latitude_rad.to_degrees()
                        ),
                        start_s: None,
                        end_s: None,
                        samples: samples.len(),
                        action: Action::Repaired,
                    });
                }
                None => {
                    return Err((
                        Kind::TimeUnits,
                        format!(
                            "gravity turns {:.3e}× as fast per time unit as the Earth's rotation predicts at latitude {:.2} deg: \
                             the time column is not in seconds (nor ms, µs, minutes or hours), or the latitude is far off",
                            1.0 / s,
                            site.latitude_rad.to_degrees()
                        ),
                    ));
                }
            }
        }
    }
    Ok(applied)
}

/// Gaps (> 5 median intervals) and a change of the sample interval (> 10 % between the first and
/// last quarter) are noted: the averager and the filter bridge both.
pub(crate) fn check_spacing(times: &[f64], findings: &mut Vec<Finding>) {
    // The intervals, recomputed from `times` where their order matters: one buffer of them for
    // the three medians (on a 60-h recording 1.7 MB of fresh memory instead of 4.3).
    let dt = |k: usize| times[k + 1] - times[k];
    let intervals = times.len().saturating_sub(1);
    if intervals < 8 {
        return;
    }
    let mut scratch: Vec<f64> = (0..intervals).map(dt).collect();
    let med = median(&mut scratch);
    let gaps: Vec<usize> = (0..intervals).filter(|&k| dt(k) > 5.0 * med).collect();
    if !gaps.is_empty() {
        let total: f64 = gaps.iter().map(|&k| dt(k) - med).sum();
        let longest = gaps
            .iter()
            .copied()
            .max_by(|&a, &b| dt(a).total_cmp(&dt(b)))
            .unwrap_or(0);
        findings.push(Finding {
            kind: Kind::TimeGap,
            message: format!(
                "{} gaps in the time axis totalling {total:.1} s (longest {:.1} s after t = {:.1} s; usual interval {med:.4} s); the filter bridges them",
                gaps.len(),
                dt(longest),
                times[longest]
            ),
            start_s: Some(times[gaps[0]]),
            end_s: Some(times[gaps[gaps.len() - 1] + 1]),
            samples: 0,
            action: Action::Noted,
        });
    }
    let q = intervals / 4;
    let mut quarter = |from: usize| {
        scratch.clear();
        scratch.extend((from..from + q).map(dt));
        median(&mut scratch)
    };
    let (first, last) = (quarter(0), quarter(intervals - q));
    if (first / last - 1.0).abs() > 0.1 {
        findings.push(Finding {
            kind: Kind::SampleRateChange,
            message: format!(
                "the sample interval changes from {first:.4} s (first quarter) to {last:.4} s (last quarter); the filter-period means use the actual times"
            ),
            start_s: None,
            end_s: None,
            samples: 0,
            action: Action::Noted,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1 000-s gap in a 10-s record and an interval that doubles in its last third: both are
    /// noted with the numbers of the record (the usual interval, the gap's extent, the two
    /// quarters' intervals), and a regular record gets no finding.
    #[test]
    fn gaps_and_a_rate_change_are_noted_with_their_numbers() {
        let mut times: Vec<f64> = (0..1000).map(|k| 10.0 * f64::from(k)).collect();
        times.extend((0..400).map(|k| 11_000.0 + 10.0 * f64::from(k)));
        times.extend((1..=700).map(|k| 14_990.0 + 20.0 * f64::from(k)));
        let mut findings = Vec::new();
        check_spacing(&times, &mut findings);
        let kinds: Vec<_> = findings.iter().map(|f| f.kind).collect();
        assert_eq!(
            kinds,
            [Kind::TimeGap, Kind::SampleRateChange],
            "{findings:?}"
        );
        let gap = &findings[0];
        assert_eq!((gap.start_s, gap.end_s), (Some(9_990.0), Some(11_000.0)));
        assert!(
            gap.message.contains("totalling 1000.0 s (longest 1010.0 s after t = 9990.0 s; usual interval 10.0000 s)"),
            "{}",
            gap.message
        );
        assert!(
            findings[1]
                .message
                .contains("from 10.0000 s (first quarter) to 20.0000 s"),
            "{}",
            findings[1].message
        );
        let mut none = Vec::new();
        check_spacing(&times[..1000], &mut none);
        assert!(none.is_empty(), "{none:?}");
    }
}
