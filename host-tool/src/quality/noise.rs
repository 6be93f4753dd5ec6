//! The accelerometer noise floor, estimated from the data themselves.
//!
//! Third differences of (nearly: [`MAX_JITTER`]) equally spaced raw samples remove the slow gravity-cone signal (its third
//! difference at 1 s is ~1e-13 m/s², at 60 s ~7e-7 m/s²) and keep white noise with variance
//! 20σ². A median-based estimate (1.4826·median|Δ³|/√20) ignores the occasional outlier.

use estimator_core::robust;
use estimator_core::Sample;

/// Raw-sample 1σ per axis (m/s²) and how many third differences it rests on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseFloor {
    /// 1σ of one raw sample, m/s², per axis.
    pub raw_sigma_mps2: [f64; 3],
    /// Number of third differences used per axis.
    pub count: usize,
}

/// Smallest raw 1σ we accept (m/s²): keeps S positive definite on noise-free simulations.
pub(crate) const MIN_RAW_SIGMA_MPS2: f64 = 1e-8;

/// Estimates the raw-sample noise from samples in time order (their times and specific forces;
/// finite). Returns `None` when fewer than 8 runs of 4 samples within [`MAX_JITTER`] of equal
/// spacing exist.
pub(crate) fn estimate(samples: &[Sample]) -> Option<NoiseFloor> {
    // Each axis on its own, the first here and the others on the pool (`crate::pool`): the
    // differences and their median are most of the screening's noise estimate, ~2 ms of a 60-h
    // recording.
    let mut axes: [Option<(usize, f64)>; 3] = [None; 3];
    crate::pool::caller_first(axes.iter_mut().enumerate(), |(a, out)| {
        *out = axis_sigma(samples, a);
    });
    let [Some((count, x)), Some((_, y)), Some((_, z))] = axes else {
        return None;
    };
    Some(NoiseFloor {
        raw_sigma_mps2: [x, y, z],
        count,
    })
}

/// Axis `a`'s third differences over runs of 4 samples within [`MAX_JITTER`] of equal spacing
/// ([`third_difference`]) and the 1σ their median gives, or `None` when fewer than 8.
fn axis_sigma(samples: &[Sample], a: usize) -> Option<(usize, f64)> {
    // |Δ³| as the bits of a non-negative f64: for finite values ≥ +0 (`abs` gives +0 for −0)
    // the integer order is the numeric order, and selecting the median among integers is about
    // twice as fast as with `f64::total_cmp` (the median is the same value).
    // Room for every difference up front: grown by doubling, the vector was moved ~18 times on
    // a 60-h recording.
    let mut d = Vec::with_capacity(samples.len().saturating_sub(3));
    d.extend(
        samples
            .windows(4)
            .filter_map(|w| third_difference(w, a))
            .map(|x| x.abs().to_bits()),
    );
    if d.len() < 8 {
        return None;
    }
    let median = robust::median_by(&mut d, Ord::cmp, f64::from_bits);
    Some((
        d.len(),
        (robust::NORMAL_SIGMA_PER_MEDIAN_ABS * median / 20f64.sqrt()).max(MIN_RAW_SIGMA_MPS2),
    ))
}

/// Largest departure of a sample interval from the mean interval of its run of four, as a
/// fraction of it, that still counts as clock jitter (time-stamp rounding, a logger's timer):
/// the third *divided* difference (times 6h³) then vanishes on any cubic whatever the spacing,
/// and rescaled to the even grid's variance 20σ² it carries the same noise; within 10 % the
/// variance of the unscaled difference is at most 1.16× the even grid's (hardly less
/// information). A stamp off the true sampling time by δ moves a difference by ~|A'|·δ: at the
/// Earth-rate turn's 7e-4 m/s² per s, 40 µs on 10-s samples or a millisecond stamp's rounding on
/// a 3-Hz logger (0.5 ms) is under 1e-6 m/s², far below any accelerometer's noise.
/// Wider departures are gaps or a change of rate, not jitter: those runs are not used.
pub(crate) const MAX_JITTER: f64 = 0.1;

/// The third difference of axis `a` over four samples: x₃ − 3x₂ + 3x₁ − x₀ when they are equally
/// spaced (to 1e-6 of their interval); within [`MAX_JITTER`] of it, the third divided difference
/// times 6h³ (h the mean interval) rescaled to the even grid's noise; `None` beyond.
fn third_difference(w: &[Sample], a: usize) -> Option<f64> {
    let t = |i: usize| w[i].t_s;
    let x = |i: usize| w[i].specific_force[a];
    let dt = t(1) - t(0);
    if (1..3).all(|i| ((t(i + 1) - t(i)) - dt).abs() <= 1e-6 * dt.abs().max(1e-9)) {
        return Some(x(3) - 3.0 * x(2) + 3.0 * x(1) - x(0));
    }
    let h = (t(3) - t(0)) / 3.0;
    if h.is_nan() || h <= 0.0 || (0..3).any(|i| !jitter(t(i + 1) - t(i), h)) {
        return None;
    }
    // Σ xᵢ / Πⱼ≠ᵢ (tᵢ − tⱼ), scaled to the even grid's form; its variance Σcᵢ² against 20.
    let c: [f64; 4] = core::array::from_fn(|i| {
        let den: f64 = (0..4).filter(|&j| j != i).map(|j| t(i) - t(j)).product();
        6.0 * h * h * h / den
    });
    let raw: f64 = (0..4).map(|i| c[i] * x(i)).sum();
    let var: f64 = c.iter().map(|v| v * v).sum();
    Some(raw * (20.0 / var).sqrt())
}

/// Whether interval `d` is within [`MAX_JITTER`] of `h` (false for NaN).
fn jitter(d: f64, h: f64) -> bool {
    (d - h).abs() <= MAX_JITTER * h
}

/// The first sample (index) whose interval to the previous one departs from the median interval
/// by more than [`MAX_JITTER`], with that interval and the median (s): where a recording whose
/// noise cannot be estimated is irregular.
pub(crate) fn first_irregular(samples: &[Sample]) -> Option<(usize, f64, f64)> {
    let mut dt: Vec<f64> = samples.windows(2).map(|w| w[1].t_s - w[0].t_s).collect();
    if dt.is_empty() {
        return None;
    }
    let med = robust::median(&mut dt);
    samples.windows(2).enumerate().find_map(|(k, w)| {
        let d = w[1].t_s - w[0].t_s;
        (!jitter(d, med)).then_some((k + 1, d, med))
    })
}
