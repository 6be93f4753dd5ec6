//! Screening of raw accelerometer samples before they are averaged: the one implementation the
//! firmware and the host both run, so that a glitch, a stuck or dead channel or a non-finite
//! value never enters a filter-period mean.
//!
//! Per axis, in this order:
//! 1. **non-finite** values (NaN, ±∞) and **all-zero samples** (a sensor that drops out reads
//!    exactly 0 on every axis, which is impossible at rest: |A| = g) are flagged;
//! 2. **stuck runs**: a run of bit-identical consecutive readings longer than white noise allows.
//!    With a per-step repeat probability `p` (measured on the axis itself, so quantisation is
//!    accounted for), a run of `L` samples has probability `p^(L−1)`; a run is flagged when
//!    `N·p^(L−1) < stuck_false_alarm` (and `L ≥ min_stuck_run`);
//! 3. **outliers** (glitches, spikes): each sample against a robust local line through the
//!    medians of its left and right neighbours (unflagged samples only), in units of the raw noise
//!    1σ given by the caller. The threshold `outlier_k` (default 8σ after the prediction's own
//!    uncertainty) never fires on Gaussian noise (P ≈ 1e-15 per sample), while the slow gravity
//!    cone signal is followed exactly by the local line.
//!
//! No heap: the caller passes the samples and a flag slice of the same length; the summary holds
//! counts. The host groups consecutive flagged samples into findings; the firmware screens its
//! sample blocks the same way.

use crate::averaging::Sample;
use crate::robust::{median_of_few, median_of_sorted, sort_few};

/// Flag bits of one sample (any bit set: the sample is rejected).
pub mod flag {
    /// A value is NaN or infinite.
    pub const NON_FINITE: u8 = 1;
    /// Every axis reads exactly zero (a dropout).
    pub const ZERO: u8 = 2;
    /// Part of a stuck run on the axis given by [`super::axis_bit`].
    pub const STUCK: u8 = 4;
    /// An outlier (glitch) on some axis.
    pub const OUTLIER: u8 = 8;
    /// Stuck on axis x (bit 4), y (bit 5), z (bit 6) — which axis stuck.
    pub const STUCK_AXIS_SHIFT: u8 = 4;
}

/// Bit marking axis `a` (0, 1, 2) in a flag byte (stuck or outlier axis).
pub const fn axis_bit(a: usize) -> u8 {
    1 << (flag::STUCK_AXIS_SHIFT as usize + a)
}

/// Thresholds of the screening (a tiny config, like a rejection criterion).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScreenConfig {
    /// Neighbours on each side used for the local line (≤ [`MAX_HALF_WINDOW`]).
    pub half_window: usize,
    /// Outlier threshold in units of the prediction error's 1σ.
    pub outlier_k: f64,
    /// Accepted probability of one false stuck run in the whole record.
    pub stuck_false_alarm: f64,
    /// Shortest run of identical readings ever called stuck.
    pub min_stuck_run: usize,
}

/// Largest `half_window` (the median buffers are fixed arrays).
pub const MAX_HALF_WINDOW: usize = 15;

impl Default for ScreenConfig {
    fn default() -> Self {
        ScreenConfig {
            half_window: 7,
            outlier_k: 8.0,
            stuck_false_alarm: 1e-6,
            min_stuck_run: 5,
        }
    }
}

/// Counts of a screening.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScreenSummary {
    /// Samples with a non-finite value.
    pub non_finite: usize,
    /// Samples reading zero on every axis.
    pub zero: usize,
    /// Samples in stuck runs, per axis.
    pub stuck: [usize; 3],
    /// Outliers per axis.
    pub outliers: [usize; 3],
    /// Probability of a repeated reading per step, per axis (quantisation makes it large).
    pub repeat_rate: [f64; 3],
    /// Samples rejected (any flag).
    pub rejected: usize,
}

/// Screens `samples` (time order) with raw noise 1σ `sigma` (m/s², per axis) and writes one flag
/// byte per sample into `flags` (same length; 0 = accepted).
pub fn screen(
    samples: &[Sample],
    sigma: &[f64; 3],
    cfg: &ScreenConfig,
    flags: &mut [u8],
) -> ScreenSummary {
    let n = samples.len().min(flags.len());
    let mut sum = screen_runs(samples, sigma, cfg, flags);
    let ordered = times_ordered(&samples[..n]);
    for a in 0..3 {
        sum.outliers[a] = flag_outliers(&samples[..n], &mut flags[..n], a, sigma[a], cfg, ordered);
    }
    sum.rejected = flags[..n].iter().filter(|f| **f != 0).count();
    sum
}

/// Steps 1 and 2 of [`screen`]: clears `flags` and flags non-finite, all-zero and stuck samples
/// (the summary's outlier and rejected counts are left 0). Step 3 is [`flag_outliers`] per axis.
pub fn screen_runs(
    samples: &[Sample],
    sigma: &[f64; 3],
    cfg: &ScreenConfig,
    flags: &mut [u8],
) -> ScreenSummary {
    let n = samples.len().min(flags.len());
    let mut sum = ScreenSummary::default();
    for (f, s) in flags.iter_mut().zip(samples) {
        *f = 0;
        if s.specific_force.iter().any(|v| !v.is_finite()) || !s.t_s.is_finite() {
            *f |= flag::NON_FINITE;
            sum.non_finite += 1;
        } else if s.specific_force.iter().all(|v| *v == 0.0) {
            *f |= flag::ZERO;
            sum.zero += 1;
        }
    }
    for a in 0..3 {
        sum.repeat_rate[a] = repeat_rate(&samples[..n], &flags[..n], a);
        sum.stuck[a] = flag_stuck(
            &samples[..n],
            &mut flags[..n],
            a,
            sum.repeat_rate[a],
            sigma[a],
            cfg,
        );
    }
    sum
}

/// Times strictly increasing (as a recording's are): each side's median time is then its
/// middle. A non-finite time is a rejected sample, never inside a window the outlier test takes.
pub fn times_ordered(s: &[Sample]) -> bool {
    s.windows(2)
        .all(|w| w[0].t_s < w[1].t_s || !(w[0].t_s.is_finite() && w[1].t_s.is_finite()))
}

/// Fraction of steps whose reading repeats the previous one exactly (accepted samples only).
fn repeat_rate(s: &[Sample], flags: &[u8], a: usize) -> f64 {
    let (mut steps, mut repeats) = (0usize, 0usize);
    for k in 1..s.len() {
        if flags[k] == 0 && flags[k - 1] == 0 {
            steps += 1;
            if s[k].specific_force[a] == s[k - 1].specific_force[a] {
                repeats += 1;
            }
        }
    }
    if steps == 0 {
        0.0
    } else {
        repeats as f64 / steps as f64
    }
}

/// Shortest run that is a stuck channel: `N·p^(L−1) < α`.
pub fn min_stuck_run(n: usize, repeat_rate: f64, cfg: &ScreenConfig) -> usize {
    let p = repeat_rate.clamp(1e-12, 1.0 - 1e-9);
    let l = 1.0 + libm::log(cfg.stuck_false_alarm / (n.max(1) as f64)) / libm::log(p);
    let l = if l.is_finite() { l.min(1e18) } else { 1e18 };
    crate::ceil_usize(l).max(cfg.min_stuck_run)
}

/// Repeat rate above which the outputs are quantised coarsely against the noise: runs then follow
/// the signal's slope, not a geometric law, and a run counts as stuck only if the signal moved
/// while it lasted (its neighbours on either side differ from it by more than `outlier_k`·σ).
pub const QUANTISED_REPEAT_RATE: f64 = 0.01;

fn flag_stuck(
    s: &[Sample],
    flags: &mut [u8],
    a: usize,
    p: f64,
    sigma: f64,
    cfg: &ScreenConfig,
) -> usize {
    let min_run = min_stuck_run(s.len(), p, cfg);
    let h = cfg.half_window.clamp(2, MAX_HALF_WINDOW);
    let moved = |start: usize, end: usize, v: f64| {
        let mut buf = [0.0; MAX_HALF_WINDOW];
        let before = start.saturating_sub(h);
        let after = (end + h).min(s.len());
        let mut jump = 0.0f64;
        for range in [before..start, end..after] {
            let m = range.len();
            if m == 0 {
                continue;
            }
            for (b, k) in buf.iter_mut().zip(range) {
                *b = s[k].specific_force[a];
            }
            let md = median_of_few(&mut buf[..m]);
            if md.is_finite() {
                jump = jump.max(libm::fabs(md - v));
            }
        }
        jump > cfg.outlier_k * sigma
    };
    let mut count = 0;
    let mut start = 0;
    while start < s.len() {
        let v = s[start].specific_force[a];
        let mut end = start + 1;
        while end < s.len() && s[end].specific_force[a] == v && flags[end] & flag::NON_FINITE == 0 {
            end += 1;
        }
        if end - start >= min_run
            && v.is_finite()
            && (p < QUANTISED_REPEAT_RATE || moved(start, end, v))
        {
            for f in &mut flags[start..end] {
                *f |= flag::STUCK | axis_bit(a);
            }
            count += end - start;
        }
        start = end;
    }
    count
}

/// [`median_of_few`] of values that usually come in order (a side's sample times:
/// increasing on the right, decreasing on the left): the middle without sorting when they are
/// monotone ([`median_of_sorted`], the same value); sorted otherwise.
fn median_of_ordered(v: &mut [f64]) -> f64 {
    let up = v.windows(2).all(|w| w[0] < w[1]);
    if !(up || v.windows(2).all(|w| w[0] > w[1])) {
        return median_of_few(v);
    }
    median_of_sorted(v)
}

/// Values and times of one side's neighbours.
type Window = ([f64; MAX_HALF_WINDOW], [f64; MAX_HALF_WINDOW]);

/// Collects up to `h` accepted neighbours of `i` on one side (value, time).
fn side(
    s: &[Sample],
    flags: &[u8],
    i: usize,
    a: usize,
    h: usize,
    left: bool,
    buf: &mut Window,
) -> usize {
    let (val, tim) = (&mut buf.0, &mut buf.1);
    let mut m = 0;
    let mut k = i;
    // Look at most REACH_WINDOWS·h samples away, so a long rejected stretch does not pull in
    // distant data.
    for _ in 0..REACH_WINDOWS * h {
        if left {
            if k == 0 {
                break;
            }
            k -= 1;
        } else {
            k += 1;
            if k >= s.len() {
                break;
            }
        }
        if flags[k] & (flag::NON_FINITE | flag::ZERO | flag::STUCK) == 0 {
            val[m] = s[k].specific_force[a];
            tim[m] = s[k].t_s;
            m += 1;
            if m == h {
                break;
            }
        }
    }
    m
}

/// Samples on each side that decide a sample's outlier verdict: [`outlier_at`] looks at most
/// 4·h neighbours away (h the half window) and reads nothing farther. So the verdicts on a
/// stretch of a record are those [`flag_outliers`] gives on the stretch with this many samples
/// (and their flags) either side, or up to the record's ends: the host screens long records
/// in such pieces on all its cores.
pub fn outlier_reach(cfg: &ScreenConfig) -> usize {
    REACH_WINDOWS * cfg.half_window.clamp(2, MAX_HALF_WINDOW)
}

/// How many half windows away a side of the outlier test collects its neighbours at most (one
/// constant for [`side`] and [`outlier_reach`], so the host's pieces always cover the reach).
const REACH_WINDOWS: usize = 4;

/// Step 3 of [`screen`] on axis `a`: flags the outliers of `s` (ORs `OUTLIER | axis_bit(a)`
/// into `flags`) and returns their number. Each verdict is [`outlier_at`]'s with the flags of
/// steps 1–2 (the outlier bits of any axis do not enter it); `ordered` is
/// [`times_ordered`] of the whole record.
pub fn flag_outliers(
    s: &[Sample],
    flags: &mut [u8],
    a: usize,
    sigma: f64,
    cfg: &ScreenConfig,
    ordered: bool,
) -> usize {
    let h = cfg.half_window.clamp(2, MAX_HALF_WINDOW);
    let len = s.len();
    if len == 0 {
        return 0;
    }
    // Where every neighbour within h is accepted (nearly everywhere), the two sides are the h
    // samples before and after i: their sorted values slide along with i (one value out, one
    // in) instead of being collected and sorted again. `judge` then sees the same values as
    // `outlier_at` would, so the verdicts are the same; elsewhere `outlier_at` decides.
    let mut left = [0.0; MAX_HALF_WINDOW];
    let mut right = [0.0; MAX_HALF_WINDOW];
    let mut sorted_for: Option<usize> = None;
    // Rejected samples in [i − h, i + h] (clipped to the record).
    let mut bad_near = (0..=h.min(len.saturating_sub(1)))
        .filter(|&k| bad(flags, k))
        .count();
    let mut count = 0;
    for i in 0..len {
        if i > h && bad(flags, i - h - 1) {
            bad_near -= 1;
        }
        if i > 0 && i + h < len && bad(flags, i + h) {
            bad_near += 1;
        }
        let regular =
            ordered && h >= 3 && i >= h && i + h < len && bad_near == usize::from(bad(flags, i));
        let outlier = if !regular {
            outlier_at(s, flags, i, a, sigma, cfg)
        } else if sigma.is_nan() || sigma <= 0.0 || bad(flags, i) {
            false
        } else {
            let v = |k: usize| s[k].specific_force[a];
            if within_range_of_window(s, i, a, h, cfg.outlier_k * sigma) {
                // Certainly no outlier: the sorted sides are not needed (rebuilt when next used).
                continue;
            }
            if sorted_for == Some(i - 1) {
                slide(&mut left[..h], v(i - 1 - h), v(i - 1));
                slide(&mut right[..h], v(i), v(i + h));
            } else {
                for (j, x) in left[..h].iter_mut().enumerate() {
                    *x = v(i - 1 - j);
                }
                for (j, x) in right[..h].iter_mut().enumerate() {
                    *x = v(i + 1 + j);
                }
                sort_few(&mut left[..h]);
                sort_few(&mut right[..h]);
            }
            sorted_for = Some(i);
            let (ml, mr, tl, tr) = sides_medians(s, i, h, &left[..h], &right[..h]);
            !surely_inlier(&s[i], a, sigma, cfg, ml, tl, mr, tr)
                && two_sided(&s[i], a, sigma, cfg, (ml, tl, h), (mr, tr, h))
        };
        if outlier {
            flags[i] |= flag::OUTLIER | axis_bit(a);
            count += 1;
        }
    }
    count
}

/// The medians `judge` would take of a regular window's two sides around sample `i` (`h`
/// each): of the sorted values `left` and `right` ([`median_of_sorted`]), and of the times,
/// which are in order (checked by the caller), so the middle ones — read from the samples in
/// place, added in the order [`median_of_sorted`] adds them (the left side is collected
/// backwards). Returns (left value, right value, left time, right time).
#[inline(always)]
fn sides_medians(
    s: &[Sample],
    i: usize,
    h: usize,
    left: &[f64],
    right: &[f64],
) -> (f64, f64, f64, f64) {
    let t = |k: usize| s[k].t_s;
    let (tl, tr) = if h % 2 == 1 {
        (t(i - 1 - h / 2), t(i + 1 + h / 2))
    } else {
        (
            0.5 * (t(i - h / 2) + t(i - 1 - h / 2)),
            0.5 * (t(i + h / 2) + t(i + 1 + h / 2)),
        )
    };
    (median_of_sorted(left), median_of_sorted(right), tl, tr)
}

/// The batch screening's quickest accept, before any median: whether sample `i` lies within
/// `k_sigma` of every value of its window `[i − h, i + h]`, with [`surely_inlier`]'s margin.
/// Both sides' medians lie within the window's range [lo, hi] (a median is a window value or the
/// mean of two, and rounding is monotone), so `surely_inlier`'s distance to them is at most
/// max(x − lo, hi − x) and its scale at most 2·max(|lo|, |hi|) + |x|: when this holds, that
/// holds, and the verdict ("no outlier") is the same. Only for a regular window (all accepted,
/// times increasing: x's time is between the sides'), as `flag_outliers` calls it.
#[inline(always)]
fn within_range_of_window(s: &[Sample], i: usize, a: usize, h: usize, k_sigma: f64) -> bool {
    let x = s[i].specific_force[a];
    // Two running minima and maxima, merged at the end: one chain of comparisons through the
    // window's 2h + 1 values was most of the batch screening's time (each waits for the last);
    // the extremes of a set do not depend on the order they are taken in.
    let min = |a: f64, b: f64| if b < a { b } else { a };
    let max = |a: f64, b: f64| if b > a { b } else { a };
    let (mut lo0, mut hi0, mut lo1, mut hi1) = (x, x, x, x);
    let mut pairs = s[i - h..=i + h].chunks_exact(2);
    for p in &mut pairs {
        let (u, v) = (p[0].specific_force[a], p[1].specific_force[a]);
        (lo0, hi0) = (min(lo0, u), max(hi0, u));
        (lo1, hi1) = (min(lo1, v), max(hi1, v));
    }
    for n in pairs.remainder() {
        let v = n.specific_force[a];
        (lo0, hi0) = (min(lo0, v), max(hi0, v));
    }
    let (lo, hi) = (min(lo0, lo1), max(hi0, hi1));
    let far = (x - lo).max(hi - x);
    let scale = 2.0 * libm::fabs(lo).max(libm::fabs(hi)) + libm::fabs(x);
    far + 1e-12 * (far + scale) <= k_sigma
}

/// Whether sample `k` is rejected before the outlier test (its neighbours' medians skip it).
fn bad(flags: &[u8], k: usize) -> bool {
    flags[k] & (flag::NON_FINITE | flag::ZERO | flag::STUCK) != 0
}

/// Replaces `out` (present, compared bit for bit) by `new` in the sorted `v`, keeping it sorted:
/// the values between the two places shift by one and `new` goes where it belongs (the
/// placement of swapping it there pairwise, with half the writes).
#[inline(always)]
fn slide(v: &mut [f64], out: f64, new: f64) {
    let len = v.len();
    let mut j = v
        .iter()
        .position(|x| x.to_bits() == out.to_bits())
        .unwrap_or(len - 1);
    if j > 0 && v[j - 1] > new {
        while j > 0 && v[j - 1] > new {
            v[j] = v[j - 1];
            j -= 1;
        }
    } else {
        while j + 1 < len && new > v[j + 1] {
            v[j] = v[j + 1];
            j += 1;
        }
    }
    v[j] = new;
}

/// Whether sample `i` of `s` is an outlier on axis `a` against the robust local line through its
/// neighbours' medians (the one outlier test, used by [`screen`] and [`Screener`]).
pub fn outlier_at(
    s: &[Sample],
    flags: &[u8],
    i: usize,
    a: usize,
    sigma: f64,
    cfg: &ScreenConfig,
) -> bool {
    let h = cfg.half_window.clamp(2, MAX_HALF_WINDOW);
    if sigma.is_nan()
        || sigma <= 0.0
        || flags[i] & (flag::NON_FINITE | flag::ZERO | flag::STUCK) != 0
    {
        return false;
    }
    let mut l: Window = ([0.0; MAX_HALF_WINDOW], [0.0; MAX_HALF_WINDOW]);
    let mut r: Window = ([0.0; MAX_HALF_WINDOW], [0.0; MAX_HALF_WINDOW]);
    let nl = side(s, flags, i, a, h, true, &mut l);
    let nr = side(s, flags, i, a, h, false, &mut r);
    judge(&s[i], a, sigma, cfg, (&mut l, nl), (&mut r, nr))
}

/// The outlier test of sample `x` on axis `a` against its two sides' neighbours (values and
/// times, `n` of each; the values are sorted in place).
fn judge(
    x: &Sample,
    a: usize,
    sigma: f64,
    cfg: &ScreenConfig,
    (l, nl): (&mut Window, usize),
    (r, nr): (&mut Window, usize),
) -> bool {
    let ((lv, lt), (rv, rt)) = (l, r);
    // Each side's median value and median time (times are increasing: the middle one).
    if nl >= 3 && nr >= 3 {
        let (ml, mr) = (median_of_few(&mut lv[..nl]), median_of_few(&mut rv[..nr]));
        let (tl, tr) = (
            median_of_ordered(&mut lt[..nl]),
            median_of_ordered(&mut rt[..nr]),
        );
        return two_sided(x, a, sigma, cfg, (ml, tl, nl), (mr, tr, nr));
    }
    let (pred, var_factor) = if nl + nr >= 3 {
        // Too few on one side (record edge, long gap): the other side's median, no slope —
        // valid only where the signal is locally flat, so widen the threshold by the spread.
        let (vals, m) = if nl >= nr { (lv, nl) } else { (rv, nr) };
        let md = median_of_few(&mut vals[..m]);
        let spread = vals[..m]
            .iter()
            .fold(0.0f64, |acc, v| acc.max(libm::fabs(v - md)));
        let extra = spread / sigma;
        (md, core::f64::consts::FRAC_PI_2 / m as f64 + extra * extra)
    } else {
        return false;
    };
    let d = libm::fabs(x.specific_force[a] - pred);
    d > cfg.outlier_k * sigma * crate::sqrt(1.0 + var_factor)
}

/// Whether [`two_sided`] certainly says "no outlier", decided without its divisions and square
/// root (the batch screening's fast path; the stream's code stays as it is). Nearly every sample
/// lies within k·σ of both medians: when x's time is between the two sides' (0 ≤ u ≤ 1, rounding
/// is monotone), the prediction is a convex combination of ml and mr up to a few ulps, and the
/// threshold is at least fl(k·σ) (√(1 + v) ≥ 1). The margin (1e-12 of the magnitudes, against
/// ~1e-15 of rounding) keeps the verdict the same.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn surely_inlier(
    x: &Sample,
    a: usize,
    sigma: f64,
    cfg: &ScreenConfig,
    ml: f64,
    tl: f64,
    mr: f64,
    tr: f64,
) -> bool {
    let x_a = x.specific_force[a];
    let inside = if tr > tl {
        tl <= x.t_s && x.t_s <= tr
    } else {
        true
    };
    if !inside {
        return false;
    }
    let far = libm::fmax(libm::fabs(x_a - ml), libm::fabs(x_a - mr));
    let scale = libm::fabs(ml) + libm::fabs(mr) + libm::fabs(x_a);
    far + 1e-12 * (far + scale) <= cfg.outlier_k * sigma
}

/// The outlier test against the line through the two sides' (median value, median time), each
/// side the median of `n` samples.
fn two_sided(
    x: &Sample,
    a: usize,
    sigma: f64,
    cfg: &ScreenConfig,
    (ml, tl, nl): (f64, f64, usize),
    (mr, tr, nr): (f64, f64, usize),
) -> bool {
    let u = if tr > tl {
        (x.t_s - tl) / (tr - tl)
    } else {
        0.5
    };
    // Prediction = (1−u)·ml + u·mr; a median of m samples has variance ≈ (π/2)σ²/m.
    let v = core::f64::consts::FRAC_PI_2 * ((1.0 - u) * (1.0 - u) / nl as f64 + u * u / nr as f64);
    let pred = (1.0 - u) * ml + u * mr;
    let d = libm::fabs(x.specific_force[a] - pred);
    d > cfg.outlier_k * sigma * crate::sqrt(1.0 + v)
}

/// Samples a [`Screener`] holds: the sample under test and `MAX_HALF_WINDOW` on each side.
pub const STREAM_WINDOW: usize = 2 * MAX_HALF_WINDOW + 1;

/// The same screening for a stream of samples (the firmware): each sample comes out
/// `half_window` samples later with its flags, judged by [`outlier_at`] on the same neighbours
/// the batch [`screen`] uses. Stuck runs are counted as they grow, with the threshold of
/// [`min_stuck_run`] for the repeat rate of the runs before (a run counts towards the rate when
/// it ends, so a channel stuck early in a stream is judged by the rate before it, not raised past
/// the quantisation limit by its own repeats; at least `expected_samples` samples are assumed, so
/// an early run is not judged on a tiny record); the first samples of a run longer than the window
/// are already out when it is recognised, so they pass. A run that is recognised while its first
/// samples are still held is rejected whole. The state can be saved and restored exactly
/// ([`Screener::save`], [`Screener::load`]: the firmware's checkpoints). A stream cannot see
/// where a run ends, so the batch's test for coarsely quantised outputs (did the signal move
/// while the run lasted?) is not available: the stream assumes outputs finer than the noise (the
/// ADXL355's 20-bit LSB, 3.9 µg, is well below its noise) and skips stuck detection on an axis
/// whose repeat rate says otherwise. No heap.
#[derive(Clone, Debug)]
pub struct Screener {
    cfg: ScreenConfig,
    sigma: [f64; 3],
    expected_samples: usize,
    buf: [Sample; STREAM_WINDOW],
    flags: [u8; STREAM_WINDOW],
    len: usize,
    emitted: usize,
    run: [usize; 3],
    steps: usize,
    repeats: [usize; 3],
    /// Counts of what was flagged so far.
    pub summary: ScreenSummary,
}

impl Screener {
    /// A screener for raw noise 1σ `sigma` (m/s², per axis), expecting about `expected_samples`
    /// samples in a run (for the stuck-run threshold).
    pub fn new(sigma: [f64; 3], cfg: ScreenConfig, expected_samples: usize) -> Self {
        let blank = Sample {
            t_s: 0.0,
            specific_force: [0.0; 3],
            temp_c: f64::NAN,
        };
        Screener {
            cfg,
            sigma,
            expected_samples,
            buf: [blank; STREAM_WINDOW],
            flags: [0; STREAM_WINDOW],
            len: 0,
            emitted: 0,
            run: [0; 3],
            steps: 0,
            repeats: [0; 3],
            summary: ScreenSummary::default(),
        }
    }

    fn h(&self) -> usize {
        self.cfg.half_window.clamp(2, MAX_HALF_WINDOW)
    }

    /// Adds a sample; returns the sample `half_window` back with its flags once it has its right
    /// neighbours (0 = accepted).
    pub fn push(&mut self, s: Sample) -> Option<(Sample, u8)> {
        let h = self.h();
        if self.len == STREAM_WINDOW {
            self.drop_front();
        }
        let mut f = 0;
        if s.specific_force.iter().any(|v| !v.is_finite()) || !s.t_s.is_finite() {
            f |= flag::NON_FINITE;
        } else if s.specific_force.iter().all(|v| *v == 0.0) {
            f |= flag::ZERO;
        }
        let prev = self
            .len
            .checked_sub(1)
            .map(|k| (self.buf[k], self.flags[k]));
        self.buf[self.len] = s;
        self.flags[self.len] = f;
        self.len += 1;
        self.track_runs(prev, s, f);
        // The oldest sample not yet out has its h right neighbours now: judge and emit it.
        let out = if self.len - self.emitted > h {
            Some(self.emit_next())
        } else {
            None
        };
        // Keep h already-emitted samples as left neighbours.
        while self.emitted > h {
            self.drop_front();
        }
        out
    }

    fn track_runs(&mut self, prev: Option<(Sample, u8)>, s: Sample, f: u8) {
        let Some((p, pf)) = prev else {
            self.run = [1; 3];
            return;
        };
        if f & flag::NON_FINITE == 0 && pf & flag::NON_FINITE == 0 {
            self.steps += 1;
        }
        for a in 0..3 {
            let same = f & flag::NON_FINITE == 0
                && pf & flag::NON_FINITE == 0
                && p.specific_force[a] == s.specific_force[a];
            if same {
                self.run[a] += 1;
            } else {
                // A run counts towards the repeat rate when it has ended, so that a run is
                // judged by the rate before it (a stuck channel early in a stream would
                // otherwise raise the rate past the quantisation limit by its own repeats).
                // Repeats inside a run already suspicious do not raise the rate.
                self.repeats[a] += self.run[a].min(self.cfg.min_stuck_run.max(1) - 1).max(1) - 1;
                self.run[a] = 1;
            }
        }
        let n = self.expected_samples.max(self.steps + 1);
        for a in 0..3 {
            let rate = self.repeats[a] as f64 / self.steps.max(1) as f64;
            // Coarse quantisation: the batch screening asks whether the signal moved during the
            // run, which a stream cannot see before the run ends; it is not judged here.
            if rate >= QUANTISED_REPEAT_RATE {
                continue;
            }
            if self.run[a] >= min_stuck_run(n, rate, &self.cfg) {
                let back = self.run[a].min(self.len);
                for k in self.len - back..self.len {
                    self.flags[k] |= flag::STUCK | axis_bit(a);
                }
            }
        }
    }

    fn drop_front(&mut self) {
        // Shifted by swaps, not `copy_within`: that was the firmware's only memmove (1.5 KB of
        // compiler_builtins in the image). The front sample ends past `len`, never read.
        for k in 1..self.len {
            self.buf.swap(k - 1, k);
            self.flags.swap(k - 1, k);
        }
        self.len -= 1;
        self.emitted = self.emitted.saturating_sub(1);
    }

    /// Judges and emits the oldest sample not yet out.
    fn emit_next(&mut self) -> (Sample, u8) {
        let i = self.emitted;
        self.judge(i);
        self.emitted += 1;
        let (s, f) = (self.buf[i], self.flags[i]);
        self.count(f);
        (s, f)
    }

    fn judge(&mut self, i: usize) {
        for a in 0..3 {
            if outlier_at(
                &self.buf[..self.len],
                &self.flags[..self.len],
                i,
                a,
                self.sigma[a],
                &self.cfg,
            ) {
                self.flags[i] |= flag::OUTLIER | axis_bit(a);
            }
        }
    }

    fn count(&mut self, f: u8) {
        let sum = &mut self.summary;
        if f & flag::NON_FINITE != 0 {
            sum.non_finite += 1;
        }
        if f & flag::ZERO != 0 {
            sum.zero += 1;
        }
        for a in 0..3 {
            if f & axis_bit(a) != 0 {
                if f & flag::STUCK != 0 {
                    sum.stuck[a] += 1;
                } else {
                    sum.outliers[a] += 1;
                }
            }
        }
        if f != 0 {
            sum.rejected += 1;
        }
    }

    /// Emits every sample still held (end of the run), judged with the neighbours there are.
    pub fn flush(&mut self, mut emit: impl FnMut(Sample, u8)) {
        while let Some((s, f)) = self.drain() {
            emit(s, f);
        }
    }

    /// Emits the oldest sample still held (end of the run), judged with the neighbours there
    /// are; `None` when every sample is out ([`Screener::flush`] one at a time).
    pub fn drain(&mut self) -> Option<(Sample, u8)> {
        (self.emitted < self.len).then(|| self.emit_next())
    }
}
/// Bytes of a [`Screener`]'s saved state at most ([`Screener::save`]): the counters and the
/// samples it holds (at most `2·half_window`, each 5 values and its flags).
pub const SCREENER_STATE_MAX: usize = STATE_HEAD + 2 * MAX_HALF_WINDOW * STATE_SAMPLE;
/// Fixed part of the saved state: held and emitted counts (1 byte each), then 16 u32: the run
/// lengths (3), the steps (1), the repeats (3) and the summary counts (non-finite, zero, stuck
/// ×3, outliers ×3, rejected).
const STATE_HEAD: usize = 2 + 16 * 4;
/// One held sample in the saved state: time, specific force (3), temperature (f64), flags.
const STATE_SAMPLE: usize = 5 * 8 + 1;

impl Screener {
    /// Bytes [`Screener::save`] writes for a screener of `cfg` holding as many samples as it
    /// can (the checkpoint of a run in progress).
    pub fn state_len(cfg: &ScreenConfig) -> usize {
        STATE_HEAD + 2 * cfg.half_window.clamp(2, MAX_HALF_WINDOW) * STATE_SAMPLE
    }

    /// The sample emitted last (it is the newest sample the caller has averaged), if any.
    pub fn last_emitted(&self) -> Option<(Sample, u8)> {
        let k = self.emitted.checked_sub(1)?;
        Some((self.buf[k], self.flags[k]))
    }

    /// Writes the screening state (little-endian; not the thresholds or σ, which come from the
    /// caller's configuration) into `buf`; returns its length, or `None` if `buf` is too short.
    /// With [`Screener::load`] a screener resumes exactly where this one stands.
    pub fn save(&self, buf: &mut [u8]) -> Option<usize> {
        let n = STATE_HEAD + self.len * STATE_SAMPLE;
        let out = buf.get_mut(..n)?;
        out[0] = self.len as u8;
        out[1] = self.emitted as u8;
        let s = &self.summary;
        let words = [
            self.run[0],
            self.run[1],
            self.run[2],
            self.steps,
            self.repeats[0],
            self.repeats[1],
            self.repeats[2],
            s.non_finite,
            s.zero,
            s.stuck[0],
            s.stuck[1],
            s.stuck[2],
            s.outliers[0],
            s.outliers[1],
            s.outliers[2],
            s.rejected,
        ];
        for (k, w) in words.iter().enumerate() {
            let w = u32::try_from(*w).unwrap_or(u32::MAX);
            out[2 + 4 * k..6 + 4 * k].copy_from_slice(&w.to_le_bytes());
        }
        for k in 0..self.len {
            let at = STATE_HEAD + k * STATE_SAMPLE;
            let x = &self.buf[k];
            let vals = [
                x.t_s,
                x.specific_force[0],
                x.specific_force[1],
                x.specific_force[2],
                x.temp_c,
            ];
            for (j, v) in vals.iter().enumerate() {
                out[at + 8 * j..at + 8 * j + 8].copy_from_slice(&v.to_le_bytes());
            }
            out[at + 40] = self.flags[k];
        }
        Some(n)
    }

    /// Restores a state written by [`Screener::save`] into this screener (made with the same
    /// configuration); `None` (and the screener unchanged) if the bytes are not such a state.
    pub fn load(&mut self, bytes: &[u8]) -> Option<()> {
        let (len, emitted) = (usize::from(*bytes.first()?), usize::from(*bytes.get(1)?));
        let h = self.h();
        if bytes.len() != STATE_HEAD + len * STATE_SAMPLE
            || len > 2 * h
            || emitted > len
            || emitted > h
            || len - emitted > h
        {
            return None;
        }
        let word = |k: usize| {
            let mut w = [0u8; 4];
            w.copy_from_slice(&bytes[2 + 4 * k..6 + 4 * k]);
            u32::from_le_bytes(w) as usize
        };
        self.len = len;
        self.emitted = emitted;
        self.run = [word(0), word(1), word(2)];
        self.steps = word(3);
        self.repeats = [word(4), word(5), word(6)];
        let s = &mut self.summary;
        s.non_finite = word(7);
        s.zero = word(8);
        s.stuck = [word(9), word(10), word(11)];
        s.outliers = [word(12), word(13), word(14)];
        s.rejected = word(15);
        for k in 0..len {
            let at = STATE_HEAD + k * STATE_SAMPLE;
            let v = |j: usize| {
                let mut b = [0u8; 8];
                b.copy_from_slice(&bytes[at + 8 * j..at + 8 * j + 8]);
                f64::from_le_bytes(b)
            };
            self.buf[k] = Sample {
                t_s: v(0),
                specific_force: [v(1), v(2), v(3)],
                temp_c: v(4),
            };
            self.flags[k] = bytes[at + 40];
        }
        Some(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A slowly turning gravity projection with deterministic pseudo-noise of 1σ ≈ `sigma`.
    fn signal(n: usize, sigma: f64) -> [Sample; 2000] {
        let mut out = [Sample {
            t_s: 0.0,
            specific_force: [0.0; 3],
            temp_c: f64::NAN,
        }; 2000];
        let mut state: u64 = 0x9e3779b97f4a7c15;
        let mut uniform = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for (k, s) in out.iter_mut().enumerate().take(n) {
            let t = k as f64;
            let w = 7.29e-5 * 0.78; // Earth rate × cos(latitude), rad/s
                                    // Sum of 12 uniforms − 6: unit variance, bounded at ±6 (no chance alarms).
            let mut noise = || (0..12).map(|_| uniform()).sum::<f64>() - 6.0;
            s.t_s = t;
            s.specific_force = [
                9.8 * libm::sin(w * t) + sigma * noise(),
                -9.8 * 0.6 * libm::sin(w * t) + sigma * noise(),
                9.8 * libm::cos(w * t) + sigma * noise(),
            ];
        }
        out
    }

    #[test]
    fn clean_signal_is_not_flagged() {
        let s = signal(2000, 7e-4);
        let mut f = [0u8; 2000];
        let sum = screen(&s, &[7e-4; 3], &ScreenConfig::default(), &mut f);
        assert_eq!(sum.rejected, 0, "{sum:?}");
    }

    #[test]
    fn glitch_stuck_zero_and_nan_are_flagged() {
        let mut s = signal(2000, 7e-4);
        s[100].specific_force[0] += 0.05; // 70σ glitch
        s[1999].specific_force[2] -= 0.05; // at the very end
        for k in 500..540 {
            s[k].specific_force[1] = s[500].specific_force[1]; // stuck y for 40 samples
        }
        s[700].specific_force = [0.0; 3];
        s[900].specific_force[2] = f64::NAN;
        let mut f = [0u8; 2000];
        let sum = screen(&s, &[7e-4; 3], &ScreenConfig::default(), &mut f);
        assert_ne!(f[100] & flag::OUTLIER, 0);
        assert_ne!(f[1999] & flag::OUTLIER, 0);
        assert!(f[500..540].iter().all(|x| x & axis_bit(1) != 0));
        assert_eq!(sum.stuck, [0, 40, 0]);
        assert_eq!(sum.zero, 1);
        assert_eq!(sum.non_finite, 1);
        // Nothing else: 1 + 1 outliers, 40 stuck, 1 zero, 1 NaN.
        assert_eq!(sum.rejected, 44, "{sum:?}");
    }

    #[test]
    fn the_stream_flags_what_the_batch_flags() {
        // The firmware's streaming screener and the host's batch screening on the same faults.
        let mut s = signal(2000, 7e-4);
        s[100].specific_force[0] += 0.05;
        s[1999].specific_force[2] -= 0.05;
        for k in 500..540 {
            s[k].specific_force[1] = s[500].specific_force[1];
        }
        s[700].specific_force = [0.0; 3];
        s[900].specific_force[2] = f64::NAN;
        let mut batch = [0u8; 2000];
        let sum = screen(&s, &[7e-4; 3], &ScreenConfig::default(), &mut batch);
        let mut st = Screener::new([7e-4; 3], ScreenConfig::default(), 2000);
        let mut stream = [0u8; 2000];
        let mut k = 0;
        for x in s.iter() {
            if let Some((_, f)) = st.push(*x) {
                stream[k] = f;
                k += 1;
            }
        }
        st.flush(|_, f| {
            stream[k] = f;
            k += 1;
        });
        assert_eq!(k, 2000);
        for i in 0..2000 {
            assert_eq!(
                stream[i] != 0,
                batch[i] != 0,
                "sample {i}: {} vs {}",
                stream[i],
                batch[i]
            );
        }
        assert_eq!(st.summary.rejected, sum.rejected);
    }

    /// Stream `s` through a screener, saving and restoring it (into a fresh one) after sample
    /// `cut`: the flags are those of the uninterrupted stream.
    fn stream_flags(s: &[Sample], cut: Option<usize>) -> [u8; 2000] {
        let mk = || Screener::new([7e-4; 3], ScreenConfig::default(), 2000);
        let mut st = mk();
        let mut out = [0u8; 2000];
        let mut k = 0;
        for (i, x) in s.iter().enumerate() {
            if let Some((_, f)) = st.push(*x) {
                out[k] = f;
                k += 1;
            }
            if cut == Some(i) {
                let mut buf = [0u8; SCREENER_STATE_MAX];
                let n = st.save(&mut buf).unwrap();
                assert!(n <= Screener::state_len(&ScreenConfig::default()));
                let mut fresh = mk();
                fresh.load(&buf[..n]).unwrap();
                let bits = |e: Option<(Sample, u8)>| {
                    e.map(|(s, f)| {
                        let v = [s.t_s, s.specific_force[0], s.specific_force[1]];
                        (v.map(f64::to_bits), s.temp_c.to_bits(), f)
                    })
                };
                assert_eq!(bits(fresh.last_emitted()), bits(st.last_emitted()));
                st = fresh;
            }
        }
        st.flush(|_, f| {
            out[k] = f;
            k += 1;
        });
        assert_eq!(k, s.len());
        out
    }

    #[test]
    fn a_saved_and_restored_screener_flags_as_the_uninterrupted_one() {
        let mut s = signal(2000, 7e-4);
        s[100].specific_force[0] += 0.05;
        for k in 500..540 {
            s[k].specific_force[1] = s[500].specific_force[1];
        }
        s[700].specific_force = [0.0; 3];
        let whole = stream_flags(&s, None);
        assert_ne!(whole[100], 0);
        for cut in [3, 97, 101, 104, 505, 520, 541, 702, 1999] {
            assert_eq!(stream_flags(&s, Some(cut)), whole, "cut after {cut}");
        }
        // Not a state: refused.
        let mut st = Screener::new([7e-4; 3], ScreenConfig::default(), 2000);
        assert!(st.load(&[200, 0]).is_none());
    }

    #[test]
    fn a_channel_stuck_early_in_a_stream_is_rejected_whole() {
        // 20 clean samples, then y frozen for 30: the run is judged by the rate before it.
        let mut s = signal(50, 7e-4);
        for k in 20..50 {
            s[k].specific_force[1] = s[20].specific_force[1];
        }
        let mut st = Screener::new([7e-4; 3], ScreenConfig::default(), 86_400);
        let mut flags = [0u8; 50];
        let mut k = 0;
        for x in &s[..50] {
            if let Some((_, f)) = st.push(*x) {
                flags[k] = f;
                k += 1;
            }
        }
        st.flush(|_, f| {
            flags[k] = f;
            k += 1;
        });
        assert!(flags[..20].iter().all(|&f| f == 0), "{flags:?}");
        assert!(
            flags[20..].iter().all(|&f| f & axis_bit(1) != 0),
            "{flags:?}"
        );
        assert_eq!(st.summary.stuck, [0, 30, 0]);
    }

    #[test]
    fn quantised_signal_raises_the_stuck_threshold() {
        let mut s = signal(2000, 7e-4);
        for x in s.iter_mut() {
            for v in x.specific_force.iter_mut() {
                *v = libm::round(*v / 0.01) * 0.01;
            }
        }
        let mut f = [0u8; 2000];
        let sum = screen(
            &s,
            &[0.01 / crate::sqrt(12.0); 3],
            &ScreenConfig::default(),
            &mut f,
        );
        assert_eq!(sum.rejected, 0, "{sum:?}");
        assert!(sum.repeat_rate[2] > 0.9);
    }

    /// The batch loop's sliding sorted windows give the verdicts of `outlier_at` sample by
    /// sample: glitches (some small enough to be borderline), rejected samples of every kind,
    /// runs of equal values and signed zeros, every window size.
    #[test]
    fn sliding_windows_agree_with_outlier_at() {
        for (seed, sigma) in [(1u64, 7e-4), (2, 3e-3), (3, 1e-5)] {
            let mut s = signal(2000, sigma);
            let mut state = 0x2545f4914f6cdd1du64 ^ seed;
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state
            };
            let mut flags = [0u8; 2000];
            for _ in 0..120 {
                let k = (next() % 2000) as usize;
                let a = (next() % 3) as usize;
                match next() % 6 {
                    0 => flags[k] |= flag::NON_FINITE,
                    1 => flags[k] |= flag::ZERO,
                    2 => flags[k] |= flag::STUCK | axis_bit(a),
                    3 => s[k].specific_force[a] = s[k.saturating_sub(1)].specific_force[a],
                    4 => s[k].specific_force[a] = if next() % 2 == 0 { 0.0 } else { -0.0 },
                    _ => s[k].specific_force[a] += sigma * (next() % 40) as f64,
                }
            }
            for half_window in [2, 3, 4, 7, 8, 15] {
                let cfg = ScreenConfig {
                    half_window,
                    ..ScreenConfig::default()
                };
                for a in 0..3 {
                    let mut batch = flags;
                    let n = flag_outliers(&s, &mut batch, a, sigma, &cfg, times_ordered(&s));
                    let mut count = 0;
                    for i in 0..2000 {
                        let one = outlier_at(&s, &flags, i, a, sigma, &cfg);
                        count += usize::from(one);
                        assert_eq!(
                            batch[i] & flag::OUTLIER != 0,
                            one,
                            "sample {i}, axis {a}, half window {half_window}"
                        );
                    }
                    assert_eq!(n, count);
                }
            }
        }
    }
}
