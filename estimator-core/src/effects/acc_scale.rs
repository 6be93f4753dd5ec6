//! Accelerometer scale-factor error: output `(1 + s_i·1e-6)·A_i` on each axis, s in ppm.

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};

/// Scale-factor error, three states in ppm.
#[derive(Clone, Copy, Debug, Default)]
pub struct AccScale;

const PPM: f64 = 1e-6;
const PARAMS: [Param; 3] = [
    Param {
        name: "SAx",
        unit: "ppm",
        prior_sigma: 300.0,
    },
    Param {
        name: "SAy",
        unit: "ppm",
        prior_sigma: 300.0,
    },
    Param {
        name: "SAz",
        unit: "ppm",
        prior_sigma: 300.0,
    },
];

impl Effect for AccScale {
    fn name(&self) -> &'static str {
        "acc-scale"
    }
    fn about(&self) -> &'static str {
        "Accelerometer scale-factor error: each accelerometer reads its specific force multiplied by \
         (1 + s). On a static run the z accelerometer sees nearly g all the time, so its scale error \
         looks like a bias; on x and y it scales the daily gravity swing. Nearly confounded with \
         bias and misalignment on one static run."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn accel_error(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let a = &ctx.specific_force;
        for i in 0..3 {
            out.value[i] += p[i] * PPM * a[i];
            out.d_params[i] = Vector3::ith(i, PPM * a[i]);
            out.d_force[(i, i)] += p[i] * PPM;
        }
    }
    fn touches_drift(&self) -> bool {
        false
    }
    fn touches_accel(&self) -> bool {
        true
    }
}
