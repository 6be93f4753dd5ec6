//! Gyro drift proportional to the platform temperature's deviation from its start value.

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};

/// Temperature sensitivity of the drift, three states in deg/h per °C (needs a `temp_c` column),
/// with the prior 1σ of each.
#[derive(Clone, Copy, Debug)]
pub struct TempDrift {
    /// Prior 1σ of each axis' sensitivity, deg/h per °C (the catalog's:
    /// [`PRIOR_SIGMA_DEG_H_PER_C`]; a smaller one where it is a set-up uncertainty marginalised
    /// at a physical size).
    pub sigma_deg_h_per_c: f64,
}

impl TempDrift {
    /// The catalog's temperature drift.
    pub const CATALOG: TempDrift = TempDrift {
        sigma_deg_h_per_c: PRIOR_SIGMA_DEG_H_PER_C,
    };
}

impl Default for TempDrift {
    fn default() -> Self {
        Self::CATALOG
    }
}

/// Prior 1σ of each axis' sensitivity, deg/h per °C: the catalog's drift size, 0.01 deg/h, over
/// the degree a laboratory's temperature moves in a run. At 0.1 the evidence charged it ~14
/// units more than a daily drift of the same size: a drift of 0.003 deg/h/°C (24 h at 30 s) was
/// not plausible and the run was trusted with DX0 5 total σ off.
pub const PRIOR_SIGMA_DEG_H_PER_C: f64 = 0.01;

const PARAMS: [Param; 3] = [
    Param {
        name: "KX",
        unit: "deg/h/degC",
        prior_sigma: PRIOR_SIGMA_DEG_H_PER_C,
    },
    Param {
        name: "KY",
        unit: "deg/h/degC",
        prior_sigma: PRIOR_SIGMA_DEG_H_PER_C,
    },
    Param {
        name: "KZ",
        unit: "deg/h/degC",
        prior_sigma: PRIOR_SIGMA_DEG_H_PER_C,
    },
];

impl Effect for TempDrift {
    fn name(&self) -> &'static str {
        "temp-drift"
    }
    fn about(&self) -> &'static str {
        "Temperature-dependent drift: the gyro drift moves with the platform temperature (thermal \
         gradients across the rotor and electrodes). Referenced to the temperature at the first \
         measurement (a constant offset belongs to D0). Only a temperature that changes during the \
         run makes it visible; it needs the recording's temp_c column."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn prior_sigma(&self, _k: usize) -> f64 {
        self.sigma_deg_h_per_c
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        for i in 0..3 {
            out.value[i] += p[i] * ctx.temp_dev_c;
            out.d_params[i] = Vector3::ith(i, ctx.temp_dev_c);
        }
    }
    fn touches_drift(&self) -> bool {
        true
    }
    fn touches_accel(&self) -> bool {
        false
    }
    fn reads_temperature(&self) -> bool {
        true
    }
}
