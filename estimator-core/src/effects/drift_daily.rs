//! Gyro drift that varies with the solar day: `w_i += C_i·cos(Ωt) + S_i·sin(Ωt)`,
//! Ω = 2π / 24 h (a laboratory's daily thermal cycle seen by the gyros, no temperature recorded).
//!
//! The platform turns against gravity with the *sidereal* day, so the paper's `D_j·A_j(t)` already
//! holds a sinusoid of any phase at nearly this period on each axis: on one run of a few days
//! the two differ by only the solar–sidereal phase slip (0.017 rad per day), and this drift is
//! mostly absorbed by the coefficients (docs/model.md, "What one run cannot see").

use core::f64::consts::TAU;

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};

/// A solar day, s.
pub const SOLAR_DAY_S: f64 = 86_400.0;

/// Daily periodic drift, six states in deg/h: per axis the cosine and sine components.
#[derive(Clone, Copy, Debug)]
pub struct DriftDaily {
    /// Prior 1σ of each component, deg/h.
    pub sigma_degph: f64,
}

impl Default for DriftDaily {
    /// Wide, as the catalog's priors must be (a prior must not bias the estimate): ~30× the
    /// size a laboratory's thermal cycle gives (the host's set-up prior for it).
    fn default() -> Self {
        DriftDaily { sigma_degph: S }
    }
}

const S: f64 = 0.01;

const PARAMS: [Param; 6] = [
    Param {
        name: "PXc",
        unit: "deg/h",
        prior_sigma: S,
    },
    Param {
        name: "PXs",
        unit: "deg/h",
        prior_sigma: S,
    },
    Param {
        name: "PYc",
        unit: "deg/h",
        prior_sigma: S,
    },
    Param {
        name: "PYs",
        unit: "deg/h",
        prior_sigma: S,
    },
    Param {
        name: "PZc",
        unit: "deg/h",
        prior_sigma: S,
    },
    Param {
        name: "PZs",
        unit: "deg/h",
        prior_sigma: S,
    },
];

impl Effect for DriftDaily {
    fn name(&self) -> &'static str {
        "drift-daily"
    }
    fn about(&self) -> &'static str {
        "Daily periodic drift: the drift follows the solar day (a laboratory's thermal cycle, no \
         temperature recorded). One run of a few days hardly separates it from the coefficients: \
         the platform turns with the sidereal day, four minutes shorter."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn prior_sigma(&self, _k: usize) -> f64 {
        self.sigma_degph
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let (s, c) = crate::trig::sincos(TAU * ctx.t_s / SOLAR_DAY_S);
        for i in 0..3 {
            out.value[i] += p[2 * i] * c + p[2 * i + 1] * s;
            out.d_params[2 * i] = Vector3::ith(i, c);
            out.d_params[2 * i + 1] = Vector3::ith(i, s);
        }
    }
    fn touches_drift(&self) -> bool {
        true
    }
    fn touches_accel(&self) -> bool {
        false
    }
}
