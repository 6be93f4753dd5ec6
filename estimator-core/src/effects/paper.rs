//! The paper's drift model (eq. 1): per gyro input axis i,
//! `w_d,i = D(i)_0 + D(i)_x·A_x + D(i)_y·A_y + D(i)_z·A_z` (deg/h; D_j in deg/h/(m/s²)).

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};

/// The 12 drift coefficients of the paper: constant and specific-force-proportional terms per axis.
#[derive(Clone, Copy, Debug, Default)]
pub struct PaperDrift;

const D0: f64 = 1.0; // deg/h prior 1σ: twice the paper's largest constant drift
const DJ: f64 = 0.2; // deg/h/(m/s²) prior 1σ: twice the paper's largest g-sensitive term

const PARAMS: [Param; 12] = [
    Param {
        name: "DX0",
        unit: "deg/h",
        prior_sigma: D0,
    },
    Param {
        name: "DXx",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
    Param {
        name: "DXy",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
    Param {
        name: "DXz",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
    Param {
        name: "DY0",
        unit: "deg/h",
        prior_sigma: D0,
    },
    Param {
        name: "DYx",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
    Param {
        name: "DYy",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
    Param {
        name: "DYz",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
    Param {
        name: "DZ0",
        unit: "deg/h",
        prior_sigma: D0,
    },
    Param {
        name: "DZx",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
    Param {
        name: "DZy",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
    Param {
        name: "DZz",
        unit: "deg/h/(m/s^2)",
        prior_sigma: DJ,
    },
];

impl Effect for PaperDrift {
    fn name(&self) -> &'static str {
        "paper"
    }
    fn about(&self) -> &'static str {
        "Gyro drift of the seed paper: a constant term per axis plus terms proportional to the \
         specific force along each platform axis (mass unbalance of the free rotor)."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let a = &ctx.specific_force;
        for i in 0..3 {
            let d = &p[4 * i..4 * i + 4];
            out.value[i] += d[0] + d[1] * a.x + d[2] * a.y + d[3] * a.z;
            let e = Vector3::ith(i, 1.0);
            out.d_params[4 * i] = e;
            out.d_params[4 * i + 1] = e * a.x;
            out.d_params[4 * i + 2] = e * a.y;
            out.d_params[4 * i + 3] = e * a.z;
            for j in 0..3 {
                out.d_force[(i, j)] += d[1 + j];
            }
        }
    }
    fn touches_drift(&self) -> bool {
        true
    }
    fn touches_accel(&self) -> bool {
        false
    }
}
