//! Gyro drift with a first-order Gauss–Markov component per axis (deg/h).

use nalgebra::Vector3;

use super::{Context, Effect, Markov, Param, Partials};
use crate::units::S_PER_H;

/// First-order Gauss–Markov gyro drift: three states m_i (deg/h) with `ṁ = −m/τ + w`.
#[derive(Clone, Copy, Debug)]
pub struct DriftMarkov {
    /// Stationary 1σ of each state, deg/h.
    pub sigma_degph: f64,
    /// Correlation time, h.
    pub tau_h: f64,
}

impl Default for DriftMarkov {
    fn default() -> Self {
        DriftMarkov {
            sigma_degph: 0.01,
            tau_h: 5.0,
        }
    }
}

const PARAMS: [Param; 3] = [
    Param {
        name: "MX",
        unit: "deg/h",
        prior_sigma: 0.01,
    },
    Param {
        name: "MY",
        unit: "deg/h",
        prior_sigma: 0.01,
    },
    Param {
        name: "MZ",
        unit: "deg/h",
        prior_sigma: 0.01,
    },
];

impl Effect for DriftMarkov {
    fn name(&self) -> &'static str {
        "drift-markov"
    }
    fn about(&self) -> &'static str {
        "Gyro drift wandering as a first-order Gauss-Markov process (correlated random drift, e.g. \
         from slow thermal or electrostatic-suspension changes): it bends the platform's turn \
         over hours and leaves low-frequency, non-white residuals that no constant coefficient explains."
    }
    fn params(&self) -> &[Param] {
        // The prior of a stationary Gauss–Markov state is its stationary σ; see `markov`.
        &PARAMS
    }
    fn drift(&self, p: &[f64], _ctx: &Context, out: Partials<'_>) {
        for i in 0..3 {
            out.value[i] += p[i];
            out.d_params[i] = Vector3::ith(i, 1.0);
        }
    }
    fn touches_drift(&self) -> bool {
        true
    }
    fn touches_accel(&self) -> bool {
        false
    }
    fn prior_sigma(&self, _k: usize) -> f64 {
        self.sigma_degph
    }
    fn markov(&self, _k: usize) -> Option<Markov> {
        let tau_s = self.tau_h * S_PER_H;
        Some(Markov {
            tau_s,
            q: 2.0 * self.sigma_degph * self.sigma_degph / tau_s,
        })
    }
}
