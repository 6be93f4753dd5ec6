//! Physical effects: named blocks of states appended to the platform angles.
//!
//! The paper's drift model is itself an effect ([`PaperDrift`], 12 coefficients), always first.
//! Every further effect (g²-sensitive drift, accelerometer bias, …) is one implementation of
//! [`Effect`]; the filter ([`crate::filter::Ekf`]) and the host's smoother treat them all the same,
//! so adding an effect never touches the filter code. An effect can
//! - add to the gyro drift rate (deg/h, platform axes): it then drives the platform angles;
//! - add to the accelerometer output (m/s²): it then enters the measurement;
//! - give its own states first-order Gauss–Markov dynamics (time constant, driving noise).
//!
//! Effects report their value *and* their partial derivatives with respect to their own
//! parameters and to the specific force; the model chains these into the analytic F and H.
//! Each implementation is tested against finite differences (see the crate's tests).

use nalgebra::{Matrix3, Vector3};

mod acc_bias;
pub mod acc_misalign;
mod acc_scale;
mod acc_temp;
mod drift_daily;
mod drift_markov;
mod drift_trend;
mod g2;
mod paper;
mod temp_drift;

pub use acc_bias::AccBias;
pub use acc_misalign::AccMisalign;
pub use acc_scale::AccScale;
pub use acc_temp::AccTemp;
pub use drift_daily::{DriftDaily, SOLAR_DAY_S};
pub use drift_markov::DriftMarkov;
pub use drift_trend::DriftTrend;
pub use g2::G2Drift;
pub use paper::PaperDrift;
pub use temp_drift::TempDrift;

/// What an effect sees at one instant.
#[derive(Clone, Copy, Debug)]
pub struct Context {
    /// Seconds since the gyros reached stable operation (θ = 0).
    pub t_s: f64,
    /// True specific force along the platform axes, `A = C·g0`, m/s².
    pub specific_force: Vector3<f64>,
    /// Platform temperature minus its value at the start of the run, °C (0 when not recorded).
    pub temp_dev_c: f64,
    /// Local north (horizontal, Earth-fixed) as a unit vector along the platform axes,
    /// `C_0^p·[0, 1, 0]`. With up `= A/|A|` and east `= north × up` it makes the columns of the
    /// attitude C_0^p (frame 0 is ENU): an effect may depend on the platform's turn about the
    /// vertical too, e.g. an azimuth-dependent term. Computed only when an effect of the model
    /// says [`Effect::uses_north`]; NaN otherwise (so a forgotten declaration fails loudly).
    pub north: Vector3<f64>,
}

/// One parameter of an effect: its name, unit and default prior 1σ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Param {
    /// Short name, e.g. `DX0`, `BAx`.
    pub name: &'static str,
    /// Unit as printed, e.g. `deg/h`, `m/s^2`.
    pub unit: &'static str,
    /// Default prior 1σ, in `unit`. Must be wide enough not to bias the estimate.
    pub prior_sigma: f64,
}

/// First-order Gauss–Markov dynamics of one state: `ṗ = −p/τ + w`, `E[w wᵀ] = q δ(t)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Markov {
    /// Correlation time, s.
    pub tau_s: f64,
    /// Driving-noise spectral density, unit²/s (`2σ²/τ` for a stationary σ).
    pub q: f64,
}

/// The value of an effect's contribution and its partial derivatives, accumulated by the model.
pub struct Partials<'a> {
    /// Value: deg/h for a drift contribution, m/s² for an accelerometer contribution. Add to it.
    pub value: &'a mut Vector3<f64>,
    /// ∂value/∂(own parameter k), one column per parameter (length = `params().len()`). Set
    /// every one of them (zeros included): the model does not clear them beforehand.
    pub d_params: &'a mut [Vector3<f64>],
    /// ∂value/∂A (specific force), per (m/s²). Add to it.
    pub d_force: &'a mut Matrix3<f64>,
}

/// A physical effect: a block of parameters (states) with its drift and/or accelerometer terms.
///
/// Implement this trait to add an effect of your own; see the README's worked example.
pub trait Effect: Sync {
    /// Catalog name used on the command line (`--with name`), e.g. `acc-bias`.
    fn name(&self) -> &str;
    /// One paragraph: what physical mechanism this is and what signature it leaves.
    fn about(&self) -> &str;
    /// The effect's parameters, in state order.
    fn params(&self) -> &[Param];
    /// Prior 1σ of parameter `k` (default: the `Param`'s); configurable effects override it.
    fn prior_sigma(&self, k: usize) -> f64 {
        self.params()[k].prior_sigma
    }
    /// Adds the effect's gyro drift rate (deg/h, platform axes) at parameters `p`.
    /// Default: the effect does not touch the drift.
    fn drift(&self, _p: &[f64], _ctx: &Context, _out: Partials<'_>) {}
    /// Adds the effect's accelerometer error (m/s², platform axes) at parameters `p`.
    /// Default: the effect does not touch the accelerometers.
    fn accel_error(&self, _p: &[f64], _ctx: &Context, _out: Partials<'_>) {}
    /// Whether [`Effect::drift`] is non-trivial (lets the filter skip work).
    fn touches_drift(&self) -> bool;
    /// Whether [`Effect::accel_error`] is non-trivial.
    fn touches_accel(&self) -> bool;
    /// Whether the effect reads [`Context::north`] (default: no). The model computes north and
    /// chains ∂/∂north into F and H only for models with such an effect (the firmware's paper
    /// model pays nothing for it); such an effect implements [`Effect::d_north`].
    fn uses_north(&self) -> bool {
        false
    }
    /// Whether the effect reads [`Context::temp_dev_c`] (default: no). Such an effect is
    /// invisible, and is not tried, on a recording whose temperature is not recorded or does not
    /// vary.
    fn reads_temperature(&self) -> bool {
        false
    }
    /// Adds ∂value/∂north of the effect's drift (`drift = true`, deg/h per unit) or
    /// accelerometer term (m/s² per unit) at parameters `p` to `d_north` (row: axis of the
    /// value, column: component of north). Called only for effects that say
    /// [`Effect::uses_north`], after [`Effect::drift`] or [`Effect::accel_error`] at the same
    /// point. Kept apart from [`Partials`] so that the models without north pay nothing.
    fn d_north(&self, _p: &[f64], _ctx: &Context, _drift: bool, _d_north: &mut Matrix3<f64>) {}
    /// Dynamics of parameter `k`: `None` (constant, the default) or first-order Gauss–Markov.
    fn markov(&self, _k: usize) -> Option<Markov> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every effect of the catalog sets all its parameter columns in each contribution it makes
    /// (the model reuses the columns without clearing them): columns pre-filled with NaN must
    /// all be overwritten.
    #[test]
    fn effects_set_every_parameter_column() {
        let effects: [&dyn Effect; 10] = [
            &PaperDrift,
            &DriftDaily::default(),
            &AccBias,
            &AccMisalign,
            &AccScale,
            &AccTemp,
            &DriftMarkov::default(),
            &DriftTrend::CATALOG,
            &G2Drift,
            &TempDrift::CATALOG,
        ];
        let ctx = Context {
            t_s: 7200.0,
            specific_force: Vector3::new(0.3, -0.2, 9.8),
            temp_dev_c: 1.5,
            north: Vector3::new(0.0, 0.9, 0.0),
        };
        for effect in effects {
            let n = effect.params().len();
            let p = [0.01; 32];
            for accel in [false, true] {
                if (accel && !effect.touches_accel()) || (!accel && !effect.touches_drift()) {
                    continue;
                }
                let mut cols = [Vector3::repeat(f64::NAN); 32];
                let (mut value, mut d_force) = (Vector3::zeros(), Matrix3::zeros());
                let out = Partials {
                    value: &mut value,
                    d_params: &mut cols[..n],
                    d_force: &mut d_force,
                };
                if accel {
                    effect.accel_error(&p[..n], &ctx, out);
                } else {
                    effect.drift(&p[..n], &ctx, out);
                }
                for (k, c) in cols[..n].iter().enumerate() {
                    assert!(
                        !c.iter().any(|v| v.is_nan()),
                        "{} column {k}",
                        effect.name()
                    );
                }
            }
        }
    }
}
