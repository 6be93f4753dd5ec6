//! Accelerometer bias: a constant offset on each platform accelerometer, m/s².

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};

/// Constant accelerometer bias, three states in m/s².
#[derive(Clone, Copy, Debug, Default)]
pub struct AccBias;

const PARAMS: [Param; 3] = [
    Param {
        name: "BAx",
        unit: "m/s^2",
        prior_sigma: 1e-3,
    },
    Param {
        name: "BAy",
        unit: "m/s^2",
        prior_sigma: 1e-3,
    },
    Param {
        name: "BAz",
        unit: "m/s^2",
        prior_sigma: 1e-3,
    },
];

impl Effect for AccBias {
    fn name(&self) -> &'static str {
        "acc-bias"
    }
    fn about(&self) -> &'static str {
        "Accelerometer bias: a constant offset in each accelerometer's output. On a static run it \
         looks like a fixed tilt of the platform, so it is nearly confounded with the initial \
         attitude, scale factor and misalignment; it shows as an offset that does not follow \
         the gravity cone."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn accel_error(&self, p: &[f64], _ctx: &Context, out: Partials<'_>) {
        for i in 0..3 {
            out.value[i] += p[i];
            out.d_params[i] = Vector3::ith(i, 1.0);
        }
    }
    fn touches_drift(&self) -> bool {
        false
    }
    fn touches_accel(&self) -> bool {
        true
    }
}
