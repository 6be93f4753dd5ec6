//! Gyro drift proportional to the platform temperature's deviation from its start value.

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};

/// Temperature sensitivity of the drift, three states in deg/h per °C (needs a `temp_c` column).
#[derive(Clone, Copy, Debug, Default)]
pub struct TempDrift;

const PARAMS: [Param; 3] = [
    Param {
        name: "KX",
        unit: "deg/h/degC",
        prior_sigma: 0.1,
    },
    Param {
        name: "KY",
        unit: "deg/h/degC",
        prior_sigma: 0.1,
    },
    Param {
        name: "KZ",
        unit: "deg/h/degC",
        prior_sigma: 0.1,
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
}
