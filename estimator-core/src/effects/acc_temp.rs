//! Accelerometer bias proportional to the platform temperature's deviation from its start value.

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};

/// Temperature sensitivity of each accelerometer's bias, three states in m/s² per °C (needs a
/// `temp_c` column). A pendulous accelerometer's bias moves with its temperature (tens of µg per
/// °C for a quartz-flexure sensor without compensation); a constant bias at the first measurement's
/// temperature belongs to `acc-bias` or, on a static run, to the start attitude.
#[derive(Clone, Copy, Debug, Default)]
pub struct AccTemp;

/// Prior 1σ of each axis' sensitivity, m/s² per °C: 10 µg per °C, the size of a compensated
/// quartz-flexure accelerometer's residual (an uncompensated one reaches a few times more; the
/// evidence charges a wider prior only logarithmically).
pub const PRIOR_SIGMA_MPS2_PER_C: f64 = 1e-4;

const PARAMS: [Param; 3] = [
    Param {
        name: "TAx",
        unit: "m/s^2/degC",
        prior_sigma: PRIOR_SIGMA_MPS2_PER_C,
    },
    Param {
        name: "TAy",
        unit: "m/s^2/degC",
        prior_sigma: PRIOR_SIGMA_MPS2_PER_C,
    },
    Param {
        name: "TAz",
        unit: "m/s^2/degC",
        prior_sigma: PRIOR_SIGMA_MPS2_PER_C,
    },
];

impl Effect for AccTemp {
    fn name(&self) -> &'static str {
        "acc-temp"
    }
    fn about(&self) -> &'static str {
        "Temperature-dependent accelerometer bias: each accelerometer's offset moves with the \
         platform temperature (the pendulum's spring and the torquer's magnet change with it). \
         Referenced to the temperature at the first measurement. Only a temperature that changes \
         during the run makes it visible; it needs the recording's temp_c column. Without it in \
         the model it is absorbed as a bias and a scale factor that follow the temperature's \
         correlation with the gravity cone."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn accel_error(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        for i in 0..3 {
            out.value[i] += p[i] * ctx.temp_dev_c;
            out.d_params[i] = Vector3::ith(i, ctx.temp_dev_c);
        }
    }
    fn touches_drift(&self) -> bool {
        false
    }
    fn touches_accel(&self) -> bool {
        true
    }
    fn reads_temperature(&self) -> bool {
        true
    }
}
