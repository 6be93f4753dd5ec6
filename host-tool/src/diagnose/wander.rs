//! A test-only stand-in for Gauss–Markov drift in the score test.
//!
//! A first-order Gauss–Markov drift is a random process, not a constant, so it has no fixed
//! "size" to score. Over a run of length T with correlation time τ it behaves like ~T/τ roughly
//! independent drift levels. We score it as a piecewise-constant drift per axis in blocks of
//! length τ: a χ² test for "the drift wanders on the time scale τ". Adding `drift-markov` to the
//! model then uses the real Gauss–Markov states.

use std::sync::OnceLock;

use estimator_core::effects::{Context, Effect, Param, Partials};
use nalgebra::Vector3;

/// Most blocks per axis.
pub(crate) const MAX_BLOCKS: usize = 12;

/// Piecewise-constant drift, `blocks` levels per axis, each `block_s` long (deg/h).
pub(crate) struct DriftWander {
    /// Block length, s.
    pub block_s: f64,
    /// Blocks per axis.
    pub blocks: usize,
    params: Vec<Param>,
}

fn names() -> &'static [String] {
    static NAMES: OnceLock<Vec<String>> = OnceLock::new();
    NAMES.get_or_init(|| {
        ["X", "Y", "Z"]
            .iter()
            .flat_map(|a| (1..=MAX_BLOCKS).map(move |b| format!("W{a}{b}")))
            .collect()
    })
}

impl DriftWander {
    /// Blocks of `block_s` covering `run_s`, at most `max_blocks` (≤ [`MAX_BLOCKS`]) per axis.
    pub(crate) fn new(block_s: f64, run_s: f64, max_blocks: usize) -> Self {
        let blocks = ((run_s / block_s).ceil() as usize).clamp(1, max_blocks.min(MAX_BLOCKS));
        let block_s = run_s / blocks as f64;
        let names = names();
        let params = (0..3)
            .flat_map(|a| (0..blocks).map(move |b| (a, b)))
            .map(|(a, b)| Param {
                name: names[a * MAX_BLOCKS + b].as_str(),
                unit: "deg/h",
                prior_sigma: 0.01,
            })
            .collect();
        DriftWander {
            block_s,
            blocks,
            params,
        }
    }
}

impl Effect for DriftWander {
    fn name(&self) -> &'static str {
        "drift-markov"
    }
    fn about(&self) -> &'static str {
        "score-test stand-in for Gauss-Markov drift: piecewise-constant drift levels per axis"
    }
    fn params(&self) -> &[Param] {
        &self.params
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let b = ((ctx.t_s / self.block_s).floor().max(0.0) as usize).min(self.blocks - 1);
        for axis in 0..3 {
            let k = axis * self.blocks + b;
            out.value[axis] += p[k];
            out.d_params[k] = Vector3::ith(axis, 1.0);
        }
    }
    fn touches_drift(&self) -> bool {
        true
    }
    fn touches_accel(&self) -> bool {
        false
    }
}
