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
    // |Δ³| as the bits of a non-negative f64: for finite values ≥ +0 (`abs` gives +0 for −0)
    // the integer order is the numeric order, and selecting the median among integers is about
    // twice as fast as with `f64::total_cmp` (the median is the same value).
    // Room for every difference up front: grown by doubling, the three vectors were moved ~18
    // times on a 60-h recording.
    let mut d3: [Vec<u64>; 3] =
        std::array::from_fn(|_| Vec::with_capacity(samples.len().saturating_sub(3)));
    for w in samples.windows(4) {
        let t = |i: usize| w[i].t_s;
        let dt = t(1) - t(0);
        let regular = (1..3).all(|i| ((t(i + 1) - t(i)) - dt).abs() <= 1e-6 * dt.abs().max(1e-9));
        if !regular {
            continue;
        }
        for (a, d) in d3.iter_mut().enumerate() {
            let x = |i: usize| w[i].specific_force[a];
            d.push((x(3) - 3.0 * x(2) + 3.0 * x(1) - x(0)).abs().to_bits());
        }
    }
    if d3[0].len() < 8 {
        return None;
    }
    let count = d3[0].len();
    let raw_sigma_mps2 = d3.map(|mut d| {
        let mid = d.len() / 2;
        let median = f64::from_bits(*d.select_nth_unstable(mid).1);
        (1.4826 * median / 20f64.sqrt()).max(MIN_RAW_SIGMA_MPS2)
    });
    Some(NoiseFloor {
        raw_sigma_mps2,
        count,
    })
}
