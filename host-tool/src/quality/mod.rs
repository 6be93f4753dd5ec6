//! Data quality: the recording checked sample by sample (the core's [`screening`]), against its
//! metadata and against physics, before anything is identified. Every defect becomes a
//! [`Finding`] the user can act on: repaired (and said so), rejected samples (and counted), not
//! repaired (the estimate is then not trusted: exit 3) or refused (no estimate: exit 2).
//!
//! Checks, each physically grounded (docs/data-quality.md):
//! - raw samples: non-finite, all-zero dropouts, stuck runs, glitches ([`screening`]); a dead axis;
//! - the time axis: its unit against the Earth's rotation seen in the gravity direction
//!   ([`time`]), gaps, a change of sample rate;
//! - gravity: the mean specific-force magnitude against the metadata gravity, outputs in g;
//!   the start: gravity along +z (platform level), or an inverted/swapped axis ([`physics`]);
//! - the noise at the filter period: window means scattering more than the raw noise predicts
//!   (quantisation, correlated noise), and steps in the means ([`steps`]).
//!
//! [`screening`]: estimator_core::screening

pub mod attitude;
pub(crate) mod exclusion;
mod finding;
pub(crate) mod hemisphere;
pub mod noise;
pub mod physics;
mod pieces;
pub mod signal;
pub mod steps;
pub mod time;

use estimator_core::screening::{self, flag, ScreenConfig, ScreenSummary};
use estimator_core::{Averager, Sample, Site};
pub use finding::{Action, Finding, Kind, Refusal};
use std::borrow::Cow;

/// The screened recording: accepted (and repaired) samples, the site, the findings.
#[derive(Clone, Debug)]
pub struct Screened<'s> {
    /// Site after repairs (gravity from the data when the metadata is wrong).
    pub site: Site,
    /// Accepted samples, in time order, repaired where a repair applies: the recording's own
    /// when every sample is accepted and none repaired (no copy of a long recording).
    pub samples: Cow<'s, [Sample]>,
    /// Raw-sample noise 1σ per axis, m/s² (robust, from accepted samples).
    pub raw_sigma_mps2: [f64; 3],
    /// Noise 1σ of one filter-period mean to use instead of raw/√n, when the means scatter more
    /// (or less) than white raw noise predicts.
    pub mean_sigma_override_mps2: Option<[f64; 3]>,
    /// The start's correction to the stated orientation (tx, ty, tz, rad) and its 1σ, when it is
    /// significant.
    pub initial_tilt: Option<([f64; 3], f64)>,
    /// Everything found, in the order checked.
    pub findings: Vec<Finding>,
    /// The screening's counts.
    pub summary: ScreenSummary,
    /// The accepted samples' filter-period means with `raw_sigma_mps2` ([`window_means`]):
    /// the steps check needs them, and `prepare` uses them as they are unless told another
    /// noise (the same means, not computed twice).
    pub means: Vec<estimator_core::Measurement>,
}

/// Fraction of rejected samples beyond which the recording is refused.
pub(crate) const MAX_REJECTED_FRACTION: f64 = 0.5;

/// Screens samples in the core's form for a run at `site` analysed at `period_s`.
pub fn screen(site: Site, samples: &[Sample], period_s: f64) -> Result<Screened<'_>, Refusal> {
    screen_oriented(site, samples, period_s, [0.0; 3])
}

/// [`screen`] for a platform whose stated orientation at t = 0 is `theta0` (rad, the paper's
/// Euler angles measured in the site's chart, [`estimator_core::frames::Chart`]; for the ENU
/// chart these are the metadata's `initial_orientation_deg`).
pub(crate) fn screen_oriented(
    site: Site,
    samples: &[Sample],
    period_s: f64,
    theta0: [f64; 3],
) -> Result<Screened<'_>, Refusal> {
    screen_excluding(site, samples, period_s, theta0, &[])
}

/// [`screen_oriented`] without the samples in the windows `exclude_s` ([t0, t1] in the
/// recording's seconds, the user's `--exclude`); the stretches pinned at a rail are left out
/// too ([`exclusion`]), each with a finding.
pub(crate) fn screen_excluding<'s>(
    mut site: Site,
    all: &'s [Sample],
    period_s: f64,
    theta0: [f64; 3],
    exclude_s: &[(f64, f64)],
) -> Result<Screened<'s>, Refusal> {
    let (kept, mut findings) = exclusion::exclude(all, period_s, exclude_s);
    let samples: &[Sample] = kept.as_deref().unwrap_or(all);
    let refuse = |findings, kind, message| Err(refused(findings, kind, message, None));
    if samples.len() < 16 {
        return refuse(
            findings,
            Kind::TooFewSamples,
            format!("{} samples; at least 16 are needed", samples.len()),
        );
    }
    // 1. Raw screening (see [`raw_screening`]).
    let (mut sigma, summary, flags) = match raw_screening(samples, &mut findings) {
        Ok(x) => x,
        Err((kind, message, at_s)) => return Err(refused(findings, kind, message, at_s)),
    };
    let mut accepted = accepted_by_screening(all, kept.as_deref(), &summary, &flags);
    // 2. Physics: gravity magnitude and units, the time axis, the start.
    let initial_tilt = match check_physics(
        &mut site,
        &mut accepted,
        &mut sigma,
        all,
        period_s,
        theta0,
        &mut findings,
    ) {
        Ok(t) => t,
        Err(f) => return refuse(findings, f.0, f.1),
    };
    // 3. Quantisation, the noise at the filter period, and steps in the means.
    let quantum = quantisation(&accepted, &summary, &mut findings);
    let means = window_means(&accepted, period_s, &sigma);
    let mean_sigma_override_mps2 = means_noise(&means, &sigma, &quantum, &mut findings);
    // Undithered rounding makes the means jump by an LSB as the signal crosses a step: no steps
    // are looked for on those axes.
    let quantised = quantum.map(|q| q.is_some());
    let disturbed = steps::check_steps(&means, &quantised, &mut findings);
    let (means, accepted_now) = drop_disturbed(means, &accepted, &disturbed, period_s);
    if let Some(a) = accepted_now {
        accepted = a.into();
    }
    let (accepted, means) = with_small_bias_steps_repaired(
        accepted,
        means,
        &quantised,
        period_s,
        &sigma,
        &mut findings,
    );
    Ok(Screened {
        site,
        samples: accepted,
        raw_sigma_mps2: sigma,
        mean_sigma_override_mps2,
        initial_tilt,
        findings,
        summary,
        means,
    })
}

/// The refusal that ends the screening: the `findings` so far and the refused one (`kind`,
/// `message`), `at_s` the time of the sample to blame when there is one.
fn refused(mut findings: Vec<Finding>, kind: Kind, message: String, at_s: Option<f64>) -> Refusal {
    findings.push(Finding {
        kind,
        message,
        start_s: None,
        end_s: None,
        samples: 0,
        action: Action::Refused,
    });
    Refusal { findings, at_s }
}

/// The samples the raw screening accepted (`flags` 0) among the ones left after the exclusions
/// (`kept`, else `all`): borrowed when nothing was left out, so a clean recording is not copied.
fn accepted_by_screening<'s>(
    all: &'s [Sample],
    kept: Option<&[Sample]>,
    summary: &ScreenSummary,
    flags: &[u8],
) -> Cow<'s, [Sample]> {
    if summary.rejected == 0 {
        match kept {
            None => Cow::Borrowed(all),
            Some(k) => Cow::Owned(k.to_vec()),
        }
    } else {
        kept.unwrap_or(all)
            .iter()
            .zip(flags)
            .filter(|(_, f)| **f == 0)
            .map(|(s, _)| *s)
            .collect()
    }
}

/// The 1σ of the filter-period means when the raw noise does not set it (m/s² per axis; `None`:
/// it does): their own scatter when correlated noise makes it larger, and the floor of the
/// quantisation on the axes `quantum` names.
fn means_noise(
    means: &[estimator_core::Measurement],
    sigma: &[f64; 3],
    quantum: &[Option<f64>; 3],
    findings: &mut Vec<Finding>,
) -> Option<[f64; 3]> {
    let over = steps::check_mean_noise(means, sigma, findings);
    if quantum.iter().any(|q| q.is_some()) {
        Some(quantised_floor(over, means, sigma, quantum))
    } else {
        over
    }
}

/// The bias-step search's means span at least this long. Each candidate is sized on ±6 h of
/// means ([`steps::REFINE_HALF_S`]): at a 1-s filter period that was 43 200 means a candidate,
/// and the search took 60 s of a 24-h run (200 s at 60 h; 25 ms at the 60-s period), growing
/// with the square of the run. Means of a minute also give the local test its calibrated reach
/// (12 means a side: 12 min, not 12 s).
const STEP_SEARCH_PERIOD_S: f64 = 60.0;

/// Bias steps too small for the third differences: found in the means (of the filter period,
/// or of [`STEP_SEARCH_PERIOD_S`] if that is longer; not on the `quantised` axes), repaired in
/// the samples (the later ones corrected, the window of those means holding the jump left out),
/// the means recomputed. A step the third differences named is replaced by its repair.
fn with_small_bias_steps_repaired<'s>(
    accepted: Cow<'s, [Sample]>,
    means: Vec<estimator_core::Measurement>,
    quantised: &[bool; 3],
    period_s: f64,
    sigma: &[f64; 3],
    findings: &mut Vec<Finding>,
) -> (Cow<'s, [Sample]>, Vec<estimator_core::Measurement>) {
    let search_s = period_s.max(STEP_SEARCH_PERIOD_S);
    let coarse;
    let searched: &[estimator_core::Measurement] = if search_s > period_s {
        coarse = window_means(&accepted, search_s, sigma);
        &coarse
    } else {
        &means
    };
    let full = steps::mean_sigma(searched, quantised);
    let found = steps::find_bias_steps(searched, quantised, &full);
    if found.is_empty() {
        return (accepted, means);
    }
    let window = if search_s > period_s {
        format!("the {}-s window", crate::format::sig(search_s, 6))
    } else {
        "the filter period".to_string()
    };
    let repaired = repair_bias_steps(&accepted, searched, &found, (search_s, &window), findings);
    let means = window_means(&repaired, period_s, sigma);
    (Cow::Owned(repaired), means)
}

/// The physics of the accepted samples: gravity's magnitude and units (`site` and `sigma` may
/// be repaired), the time axis (units, spacing of the recording's own times `all`), the start's
/// orientation and the hemisphere. Returns the initial tilt levelled from the data; or why the
/// recording is refused.
#[allow(clippy::type_complexity)]
fn check_physics(
    site: &mut Site,
    accepted: &mut Cow<'_, [Sample]>,
    sigma: &mut [f64; 3],
    all: &[Sample],
    period_s: f64,
    theta0: [f64; 3],
    findings: &mut Vec<Finding>,
) -> Result<Option<([f64; 3], f64)>, (Kind, String)> {
    physics::check_gravity(site, accepted, sigma, findings)?;
    let factor = time::check_units(site, accepted, findings)?;
    // On the times in seconds (a time column in ms would read as 1000-s samples).
    findings.extend(signal::no_noise(accepted, sigma));
    // The recording's own times (an excluded stretch is no gap in the recording).
    let times: Vec<f64> = all
        .iter()
        .map(|s| s.t_s * factor)
        .filter(|t| t.is_finite())
        .collect();
    time::check_spacing(&times, findings);
    let initial_tilt = physics::check_start(site, accepted, period_s, sigma, theta0, findings)?;
    // After the start's orientation (an inverted or swapped axis is named there first).
    hemisphere::check_hemisphere(site, accepted)?;
    Ok(initial_tilt)
}

/// The raw screening, twice: the second pass with the noise of the accepted samples only (a long
/// stuck run would otherwise pull the median-based noise estimate down). Returns the raw noise,
/// the summary and each sample's flags, the flagged stretches added to `findings`; or why the
/// recording is refused (kind, words, the time to name).
#[allow(clippy::type_complexity)]
fn raw_screening(
    samples: &[Sample],
    findings: &mut Vec<Finding>,
) -> Result<([f64; 3], ScreenSummary, Vec<u8>), (Kind, String, Option<f64>)> {
    let cfg = ScreenConfig::default();
    let mut flags = vec![0u8; samples.len()];
    let Some(sigma0) = raw_noise_sigma(samples, &flags) else {
        // Named by its time (the CLI adds the file's line): an index would count the samples
        // left after `--exclude`, not the file's rows.
        let irregular = noise::first_irregular(samples);
        let place = match irregular {
            Some((k, d, med)) => format!(
                "; the times are irregular from t = {} s: {d:.6} s after the previous sample against a median interval of {med:.6} s (more than {:.0} % off: no clock jitter)",
                samples[k].t_s,
                100.0 * noise::MAX_JITTER
            ),
            None => String::new(),
        };
        return Err((
            Kind::TooFewSamples,
            format!(
                "fewer than 8 runs of 4 finite samples equally spaced to within {:.0} % of their interval (clock jitter): cannot estimate the noise{place}",
                100.0 * noise::MAX_JITTER
            ),
            irregular.map(|(k, _, _)| samples[k].t_s),
        ));
    };
    // The glitch test screens the residual of a model of the slow signal where a line through
    // the neighbours would miss its curvature (slow logs, noise-free records: [`signal`]).
    let series = signal::outlier_series(samples, &sigma0);
    let first = pieces::screen(samples, &series, &sigma0, &cfg, &mut flags);
    // The screening is a function of the samples and the noise alone (it rewrites every flag):
    // when the first pass rejected nothing, the noise of the accepted samples is sigma0 itself
    // and the second pass would repeat the first bit for bit (half of `prepare` on clean data).
    let (sigma, summary) = if first.rejected == 0 {
        (sigma0, first)
    } else {
        let sigma = raw_noise_sigma(samples, &flags).unwrap_or(sigma0);
        let summary = pieces::screen(samples, &series, &sigma, &cfg, &mut flags);
        (sigma, summary)
    };
    if let Some(f) = dead_axis(samples, &flags) {
        return Err((Kind::DeadAxis, f, None));
    }
    findings.extend(group_flags(samples, &flags, &summary));
    if summary.rejected as f64 > MAX_REJECTED_FRACTION * samples.len() as f64 {
        return Err((
            Kind::TooManyRejected,
            format!(
                "{} of {} samples rejected (more than {:.0} %)",
                summary.rejected,
                samples.len(),
                100.0 * MAX_REJECTED_FRACTION
            ),
            None,
        ));
    }
    Ok((sigma, summary, flags))
}

/// The bias steps `found` in `means` (of `period_s`, called `window` in the finding) repaired in
/// the samples: every later sample corrected by the step, the period holding the jump left
/// out; each named as an
/// `acc-bias-step` finding (replacing a `step` the third differences named there). Returns the
/// repaired samples.
fn repair_bias_steps(
    accepted: &[Sample],
    means: &[estimator_core::Measurement],
    found: &[steps::BiasStep],
    (period_s, window): (f64, &str),
    findings: &mut Vec<Finding>,
) -> Vec<Sample> {
    let p = period_s.max(1e-9);
    let transitional: Vec<f64> = found
        .iter()
        .map(|b| (means[b.at].t_s / p).floor())
        .collect();
    let mut repaired: Vec<Sample> = Vec::with_capacity(accepted.len());
    for s in accepted.iter() {
        let w = (s.t_s / p).floor();
        if transitional.contains(&w) {
            continue;
        }
        let mut s = *s;
        for (b, tw) in found.iter().zip(&transitional) {
            if w > *tw {
                s.specific_force[b.axis] -= b.size;
            }
        }
        repaired.push(s);
    }
    for b in found {
        let tag = format!("axis {}:", axis_name(b.axis));
        let (t0, t1) = (means[b.at].t_s - p, means[b.at].t_s + p);
        findings.retain(|f| {
            !(f.kind == Kind::Step
                && f.message.starts_with(&tag)
                && f.start_s.is_some_and(|a| a <= t1)
                && f.end_s.is_some_and(|e| e >= t0))
        });
        findings.push(Finding {
            kind: Kind::AccBiasStep,
            message: format!(
                "axis {}: the accelerometer bias steps by {:+.3e} ± {:.1e} m/s^2 ({:.0}σ) at t = {:.0} s ({:.3} h): found as a level shift of the \
                 filter-period means across it (a cubic for the slow signal plus a step, {} means each side) and sized on ±6 h of them (the Earth-rate turn of gravity, \
                 modulated by a cubic, plus the step); repaired: every later sample corrected by {:+.3e} m/s^2, {} holding the jump left out",
                axis_name(b.axis),
                b.size,
                b.sigma,
                (b.size / b.sigma).abs(),
                b.t_s,
                b.t_s / 3600.0,
                steps::SIDE_MEANS,
                -b.size,
                window
            ),
            start_s: Some(b.t_s),
            end_s: None,
            samples: means[b.at].count as usize,
            action: Action::Repaired,
        });
    }
    repaired
}
/// The disturbed filter periods (indices into `means`, sorted) left out of the means and of the
/// samples (the windows [k·T, (k+1)·T) holding those means); `None`: nothing disturbed.
fn drop_disturbed(
    means: Vec<estimator_core::Measurement>,
    accepted: &[Sample],
    disturbed: &[usize],
    period_s: f64,
) -> (Vec<estimator_core::Measurement>, Option<Vec<Sample>>) {
    if disturbed.is_empty() {
        return (means, None);
    }
    let p = period_s.max(1e-9);
    let windows: Vec<f64> = disturbed
        .iter()
        .map(|&i| (means[i].t_s / p).floor())
        .collect();
    let accepted = accepted
        .iter()
        .filter(|s| !windows.contains(&(s.t_s / p).floor()))
        .copied()
        .collect();
    let means = means
        .into_iter()
        .enumerate()
        .filter(|(i, _)| disturbed.binary_search(i).is_err())
        .map(|(_, m)| m)
        .collect();
    (means, Some(accepted))
}

/// The floor of a filter-period mean on quantised axes: at least LSB/√12, over the override the
/// means' scatter set (or the raw noise over a full window's count — as `prepare` scales the
/// override to each window's count —, not the mean count, which the partial first and last
/// windows pull down).
fn quantised_floor(
    over: Option<[f64; 3]>,
    means: &[estimator_core::Measurement],
    sigma: &[f64; 3],
    quantum: &[Option<f64>; 3],
) -> [f64; 3] {
    let mut over = over.unwrap_or_else(|| {
        let n = steps::typical_count(means);
        sigma.map(|s| s / n.sqrt())
    });
    for (o, q) in over.iter_mut().zip(quantum) {
        if let Some(q) = q {
            *o = o.max(q / 12f64.sqrt());
        }
    }
    over
}

/// Repeat rate beyond which the noise does not dither the outputs' rounding.
pub(crate) const UNDITHERED_REPEAT_RATE: f64 = 0.5;

/// The output step (LSB) of each axis whose rounding the noise does not dither: most consecutive
/// readings repeat, so the rounding error follows the slowly turning signal and does not average
/// out over a window. The floor of a mean is then at least q/√12 (not over √n), and the estimate
/// is not trusted.
fn quantisation(
    samples: &[Sample],
    sum: &ScreenSummary,
    findings: &mut Vec<Finding>,
) -> [Option<f64>; 3] {
    let mut out = [None; 3];
    for (a, o) in out.iter_mut().enumerate() {
        if sum.repeat_rate[a] <= UNDITHERED_REPEAT_RATE {
            continue;
        }
        let Some(q) = lsb(samples, a) else { continue };
        *o = Some(q);
        findings.push(Finding {
            kind: Kind::Quantization,
            message: format!(
                "axis {}: outputs come in steps of {q:.3e} m/s^2 and {:.0} % of consecutive readings repeat: the noise does not dither the rounding, \
                 whose error follows the slowly turning signal and does not average out; the floor of a filter-period mean is set to q/√12 = {:.2e} m/s^2 \
                 (the 1σ grow accordingly), and the estimate is not trusted",
                axis_name(a),
                100.0 * sum.repeat_rate[a],
                q / 12f64.sqrt()
            ),
            start_s: None,
            end_s: None,
            samples: samples.len(),
            action: Action::NotRepaired,
        });
    }
    out
}

/// The output step of axis `a`: a low quantile of the non-zero differences between readings.
fn lsb(samples: &[Sample], a: usize) -> Option<f64> {
    let mut nz: Vec<f64> = samples
        .windows(2)
        .map(|w| (w[1].specific_force[a] - w[0].specific_force[a]).abs())
        .filter(|d| *d > 0.0)
        .collect();
    if nz.is_empty() {
        return None;
    }
    let k = nz.len() / 20;
    Some(*nz.select_nth_unstable_by(k, f64::total_cmp).1)
}

/// Raw-sample noise 1σ per axis of the accepted samples: the noise floor of their third
/// differences ([`noise::estimate`], robust), at least an output step's rounding error.
fn raw_noise_sigma(samples: &[Sample], flags: &[u8]) -> Option<[f64; 3]> {
    let ok = |s: &Sample, f: u8| {
        f == 0 && s.t_s.is_finite() && s.specific_force.iter().all(|v| v.is_finite())
    };
    // In place when every sample counts (a clean record, the first pass): a copy was ~7 MB to
    // fault in on a 60-h recording.
    let all = samples.len() == flags.len() && samples.iter().zip(flags).all(|(s, f)| ok(s, *f));
    let accepted: Cow<'_, [Sample]> = if all {
        Cow::Borrowed(samples)
    } else {
        samples
            .iter()
            .zip(flags)
            .filter(|(s, f)| ok(s, **f))
            .map(|(s, _)| *s)
            .collect()
    };
    let mut sigma = noise::estimate(&accepted)?.raw_sigma_mps2;
    // Quantised outputs: when many steps repeat the reading, third differences are often 0 and
    // their median collapses; the rounding error of one LSB q is then the floor, q/√12.
    let steps = accepted.len().saturating_sub(1);
    for (ax, s) in sigma.iter_mut().enumerate() {
        let repeats = accepted
            .windows(2)
            .filter(|w| w[1].specific_force[ax] == w[0].specific_force[ax])
            .count();
        if steps >= 8 && repeats * 5 > steps {
            if let Some(q) = lsb(&accepted, ax) {
                *s = s.max(q / 12f64.sqrt());
            }
        }
    }
    Some(sigma)
}

/// An axis whose every finite reading is the same value (or that has none).
fn dead_axis(samples: &[Sample], flags: &[u8]) -> Option<String> {
    for a in 0..3 {
        let mut vals = samples
            .iter()
            .zip(flags)
            .filter(|(_, f)| **f & flag::NON_FINITE == 0)
            .map(|(s, _)| s.specific_force[a]);
        let Some(first) = vals.next() else {
            return Some(format!("axis {} has no finite reading", axis_name(a)));
        };
        if vals.all(|v| v == first) {
            return Some(format!(
                "axis {} is dead: every one of {} readings is {first} m/s^2",
                axis_name(a),
                samples.len()
            ));
        }
    }
    None
}

/// `x`, `y` or `z`.
pub(crate) fn axis_name(a: usize) -> char {
    ['x', 'y', 'z'][a.min(2)]
}

/// Findings from the flags: one per stuck run (the longest 10 listed, then a summary), one for all
/// glitches, one for dropouts, one for non-finite samples.
fn group_flags(samples: &[Sample], flags: &[u8], sum: &ScreenSummary) -> Vec<Finding> {
    let mut out = vec![];
    if sum.non_finite > 0 {
        let (n, a, b) = flagged_span(samples, flags, flag::NON_FINITE);
        out.push(Finding {
            kind: Kind::NonFinite,
            message: format!("{n} samples with a NaN or infinite value"),
            start_s: a,
            end_s: b,
            samples: n,
            action: Action::Rejected,
        });
    }
    if sum.zero > 0 {
        let (n, a, b) = flagged_span(samples, flags, flag::ZERO);
        out.push(Finding {
            kind: Kind::Dropout,
            message: format!(
                "{n} samples read exactly 0 on every axis (at rest |A| = g): sensor dropouts"
            ),
            start_s: a,
            end_s: b,
            samples: n,
            action: Action::Rejected,
        });
    }
    for ax in 0..3 {
        out.extend(stuck_findings(samples, flags, sum, ax));
    }
    let glitches: usize = sum.outliers.iter().sum();
    if glitches > 0 {
        out.push(glitch_finding(samples, flags, sum));
    }
    out
}

/// How many samples carry flag `bit`, and the times of the first and last, s.
fn flagged_span(samples: &[Sample], flags: &[u8], bit: u8) -> (usize, Option<f64>, Option<f64>) {
    let mut n = 0;
    let (mut a, mut b) = (None, None);
    for (s, f) in samples.iter().zip(flags) {
        if f & bit != 0 {
            n += 1;
            a = a.or(Some(s.t_s));
            b = Some(s.t_s);
        }
    }
    (n, a, b)
}

/// Axis `ax`'s stuck runs, longest first: one finding each for the ten longest, one for the rest.
fn stuck_findings(
    samples: &[Sample],
    flags: &[u8],
    sum: &ScreenSummary,
    ax: usize,
) -> Vec<Finding> {
    let mut out = vec![];
    let bit = screening::axis_bit(ax);
    // A dropout (every axis exactly 0) is reported as a dropout, not also as a stuck run
    // on each axis.
    let stuck_here = |f: u8| f & flag::STUCK != 0 && f & bit != 0 && f & flag::ZERO == 0;
    let mut runs = vec![];
    let mut k = 0;
    while k < samples.len() {
        if stuck_here(flags[k]) {
            let start = k;
            while k < samples.len() && stuck_here(flags[k]) {
                k += 1;
            }
            runs.push((start, k));
        } else {
            k += 1;
        }
    }
    runs.sort_by_key(|(a, b)| std::cmp::Reverse(b - a));
    let min_run =
        screening::min_stuck_run(samples.len(), sum.repeat_rate[ax], &ScreenConfig::default());
    for (i, &(a, b)) in runs.iter().enumerate() {
        if i == 10 {
            let rest: usize = runs[10..].iter().map(|(a, b)| b - a).sum();
            out.push(Finding {
                kind: Kind::Stuck,
                message: format!(
                    "axis {}: {} more stuck runs, {rest} samples",
                    axis_name(ax),
                    runs.len() - 10
                ),
                start_s: None,
                end_s: None,
                samples: rest,
                action: Action::Rejected,
            });
            break;
        }
        out.push(Finding {
            kind: Kind::Stuck,
            message: format!(
                "axis {} repeats {} m/s^2 for {} samples (noise makes a run of {} already improbable)",
                axis_name(ax),
                samples[a].specific_force[ax],
                b - a,
                min_run
            ),
            start_s: Some(samples[a].t_s),
            end_s: Some(samples[b - 1].t_s),
            samples: b - a,
            action: Action::Rejected,
        });
    }
    out
}

/// The glitches (samples departing from their neighbours), with the first five times.
fn glitch_finding(samples: &[Sample], flags: &[u8], sum: &ScreenSummary) -> Finding {
    let (n, a, b) = flagged_span(samples, flags, flag::OUTLIER);
    let first: Vec<String> = samples
        .iter()
        .zip(flags)
        .filter(|(_, f)| **f & flag::OUTLIER != 0)
        .take(5)
        .map(|(s, _)| format!("{:.1} s", s.t_s))
        .collect();
    Finding {
        kind: Kind::Glitch,
        message: format!(
            "{n} samples depart from their neighbours by more than {}σ of the raw noise (x {}, y {}, z {}; first at {})",
            ScreenConfig::default().outlier_k,
            sum.outliers[0],
            sum.outliers[1],
            sum.outliers[2],
            first.join(", ")
        ),
        start_s: a,
        end_s: b,
        samples: n,
        action: Action::Rejected,
    }
}

/// Filter-period means of accepted samples (the core's averager; raw noise `sigma`).
pub(crate) fn window_means(
    samples: &[Sample],
    period_s: f64,
    sigma: &[f64; 3],
) -> Vec<estimator_core::Measurement> {
    let mut avg = Averager::new(period_s, *sigma);
    let mut out: Vec<_> = samples.iter().filter_map(|s| avg.push(s)).collect();
    out.extend(avg.flush());
    out
}
