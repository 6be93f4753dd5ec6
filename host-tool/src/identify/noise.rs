//! The accelerometer noise floor, estimated from the data themselves.
//!
//! Third differences of equally spaced raw samples remove the slow gravity-cone signal (its third
//! difference at 1 s is ~1e-13 m/s², at 60 s ~7e-7 m/s²) and keep white noise with variance
//! 20σ². A median-based estimate (1.4826·median|Δ³|/√20) ignores the occasional outlier.

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
pub const MIN_RAW_SIGMA_MPS2: f64 = 1e-8;

/// Estimates the raw-sample noise from samples in time order (their times and specific forces;
/// finite). Returns `None` when fewer than 8 runs of 4 equally spaced samples exist.
pub fn estimate(samples: &[Sample]) -> Option<NoiseFloor> {
    // Each axis on its own, the first here and the others on the pool (`crate::beside`): the
    // differences and their median are most of the screening's noise estimate, ~2 ms of a 60-h
    // recording.
    let mut axes: [Option<(usize, f64)>; 3] = [None; 3];
    crate::beside::first_here(axes.iter_mut().enumerate(), |(a, out)| {
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

/// Axis `a`'s third differences over runs of 4 equally spaced samples and the 1σ their median
/// gives, or `None` when fewer than 8.
fn axis_sigma(samples: &[Sample], a: usize) -> Option<(usize, f64)> {
    // |Δ³| as the bits of a non-negative f64: for finite values ≥ +0 (`abs` gives +0 for −0)
    // the integer order is the numeric order, and selecting the median among integers is about
    // twice as fast as with `f64::total_cmp` (the median is the same value).
    // Room for every difference up front: grown by doubling, the vector was moved ~18 times on
    // a 60-h recording.
    let mut d = Vec::with_capacity(samples.len().saturating_sub(3));
    d.extend(samples.windows(4).filter(|w| regular(w)).map(|w| {
        let x = |i: usize| w[i].specific_force[a];
        (x(3) - 3.0 * x(2) + 3.0 * x(1) - x(0)).abs().to_bits()
    }));
    if d.len() < 8 {
        return None;
    }
    let mid = d.len() / 2;
    let median = f64::from_bits(*d.select_nth_unstable(mid).1);
    Some((
        d.len(),
        (1.4826 * median / 20f64.sqrt()).max(MIN_RAW_SIGMA_MPS2),
    ))
}

/// Whether four samples are equally spaced in time (to 1e-6 of their interval).
fn regular(w: &[Sample]) -> bool {
    let t = |i: usize| w[i].t_s;
    let dt = t(1) - t(0);
    (1..3).all(|i| ((t(i + 1) - t(i)) - dt).abs() <= 1e-6 * dt.abs().max(1e-9))
}
