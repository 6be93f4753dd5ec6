//! Gyro constant drift changing linearly with time: `w_i += k_i·t` (k in deg/h per h).

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};
use crate::units::S_PER_H;

/// Drift trend, three states in deg/h per h, with the prior 1σ of each.
#[derive(Clone, Copy, Debug)]
pub struct DriftTrend {
    /// Prior 1σ of each axis' trend, deg/h per h (the catalog's: [`PRIOR_SIGMA_DEG_H_PER_H`]; a
    /// smaller one where the trend is a set-up uncertainty marginalised at a physical size).
    pub sigma_deg_h_per_h: f64,
}

impl DriftTrend {
    /// The catalog's trend.
    pub const CATALOG: DriftTrend = DriftTrend {
        sigma_deg_h_per_h: PRIOR_SIGMA_DEG_H_PER_H,
    };
}

impl Default for DriftTrend {
    fn default() -> Self {
        Self::CATALOG
    }
}

/// Prior 1σ of each axis' trend, deg/h per h: the catalog's drift size, 0.01 deg/h (a warm-up's
/// amplitude, a step, a daily cycle, a Markov drift), reached over a day. The evidence charges
/// each effect for its prior's width, so the priors must mean the same physical size: at
/// 0.01 deg/h per *hour* (0.6 deg/h over a 60-h run) the trend paid ~19 units more than a
/// warm-up of the same shape, and a trend of 1e-5 deg/h per h was named a 28-h warm-up in 18
/// of 30 runs, the latitude bending to absorb the difference.
pub const PRIOR_SIGMA_DEG_H_PER_H: f64 = 0.01 / 24.0;

const PARAMS: [Param; 3] = [
    Param {
        name: "TX",
        unit: "deg/h/h",
        prior_sigma: PRIOR_SIGMA_DEG_H_PER_H,
    },
    Param {
        name: "TY",
        unit: "deg/h/h",
        prior_sigma: PRIOR_SIGMA_DEG_H_PER_H,
    },
    Param {
        name: "TZ",
        unit: "deg/h/h",
        prior_sigma: PRIOR_SIGMA_DEG_H_PER_H,
    },
];

impl Effect for DriftTrend {
    fn name(&self) -> &'static str {
        "drift-trend"
    }
    fn about(&self) -> &'static str {
        "Drift trend: the constant drift changes linearly over the run (rotor run-in, slow thermal \
         settling, ageing of the suspension). The platform error then grows quadratically in time; \
         on one static run its signature is close to g²-sensitive drift."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn prior_sigma(&self, _k: usize) -> f64 {
        self.sigma_deg_h_per_h
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let t_h = ctx.t_s / S_PER_H;
        for i in 0..3 {
            out.value[i] += p[i] * t_h;
            out.d_params[i] = Vector3::ith(i, t_h);
        }
    }
    fn touches_drift(&self) -> bool {
        true
    }
    fn touches_accel(&self) -> bool {
        false
    }
}
