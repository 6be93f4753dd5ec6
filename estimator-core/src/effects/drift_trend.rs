//! Gyro constant drift changing linearly with time: `w_i += k_i·t` (k in deg/h per h).

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};
use crate::units::S_PER_H;

/// Drift trend, three states in deg/h per h.
#[derive(Clone, Copy, Debug, Default)]
pub struct DriftTrend;

const PARAMS: [Param; 3] = [
    Param {
        name: "TX",
        unit: "deg/h/h",
        prior_sigma: 0.01,
    },
    Param {
        name: "TY",
        unit: "deg/h/h",
        prior_sigma: 0.01,
    },
    Param {
        name: "TZ",
        unit: "deg/h/h",
        prior_sigma: 0.01,
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
