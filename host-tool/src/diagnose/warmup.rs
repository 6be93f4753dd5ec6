//! A gyro warm-up transient: after turn-on a gyro's drift settles exponentially,
//! `w_i += A_i e^{−t/τ}` (deg/h), as its rotor, suspension and electronics reach their working
//! temperatures. Without a temperature column (`temp-drift` needs one) it is a candidate of its
//! own, found like the drift step ([`super::drift_step`]): the amplitudes enter linearly, so every
//! time constant τ is weighed linearised about the current fit, from one replay a stage
//! ([`super::profile`]); τ runs over
//! [`TAUS_H`] and then every ×1.05 within the best cell, and the best is refitted and charged the
//! look-elsewhere penalty 2 ln N of the N coarse values tried.

use estimator_core::effects::{Context, Effect, Param, Partials};
use estimator_core::units::S_PER_H;
use nalgebra::Vector3;

use super::select::{refit_effect, Profiled, Refit};
use super::DiagnoseConfig;
use crate::identify::{Identification, Prepared};

/// Prior 1σ of each axis' amplitude, deg/h.
pub const PRIOR_SIGMA_DEGPH: f64 = 0.01;
/// Time constants tried, h: ×1.5 from half an hour to a day (a warm-up outlasting the run is a
/// trend, and one shorter than a filter period or two is not seen).
pub const TAUS_H: [f64; 10] = [0.5, 0.75, 1.125, 1.69, 2.53, 3.8, 5.7, 8.5, 12.8, 19.2];

pub(crate) const PARAMS: [Param; 3] = [
    Param {
        name: "AWX",
        unit: "deg/h",
        prior_sigma: PRIOR_SIGMA_DEGPH,
    },
    Param {
        name: "AWY",
        unit: "deg/h",
        prior_sigma: PRIOR_SIGMA_DEGPH,
    },
    Param {
        name: "AWZ",
        unit: "deg/h",
        prior_sigma: PRIOR_SIGMA_DEGPH,
    },
];

/// The warm-up transient of time constant `tau_s`: `w_i += A_i e^{−t/τ}` (deg/h).
#[derive(Clone, Copy, Debug)]
pub struct DriftWarmup {
    /// Time constant, s.
    pub tau_s: f64,
}

impl Effect for DriftWarmup {
    fn name(&self) -> &'static str {
        "drift-warmup"
    }
    fn about(&self) -> &'static str {
        "A gyro warm-up transient: the drift settles exponentially after turn-on (the platform \
         turns faster or slower in the first hours, then steadies)."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let e = (-ctx.t_s.max(0.0) / self.tau_s).exp();
        for i in 0..3 {
            out.value[i] += p[i] * e;
            out.d_params[i] = Vector3::ith(i, e);
        }
    }
    fn touches_drift(&self) -> bool {
        true
    }
    fn touches_accel(&self) -> bool {
        false
    }
}

/// The best time constant for `id`'s fit ([`super::profile::Fit`], its value τ; `None`: the run
/// is too short — under 3 h — or every pass failed).
pub fn profile(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &crate::identify::Config,
    id: &Identification,
) -> Option<super::profile::Fit> {
    let end_s = prep.measurements.last()?.t_s;
    if id.trajectory.len() != prep.measurements.len() + 1 || end_s < 3.0 * S_PER_H {
        return None;
    }
    let coarse_s: Vec<f64> = TAUS_H.iter().map(|h| h * S_PER_H).collect();
    // Within the best coarse cell, every ×FINE_RATIO: the amplitudes depend on τ, and the coarse
    // grid's τ left them ~3σ off on a 3-h transient.
    let grid = super::profile::Grid {
        coarse_s: &coarse_s,
        ratio: FINE_RATIO,
        steps: FINE_STEPS,
        made: Profiled::WarmupTauS,
        penalty: penalty(),
    };
    super::profile::over(prep, effects, cfg, id, &grid, |_| true)
}

/// The fine grid within a coarse cell of [`TAUS_H`]: ×1.05, 8 steps each way (1.05⁸ ≈ 1.48).
const FINE_RATIO: f64 = 1.05;
const FINE_STEPS: i32 = 8;

/// The look-elsewhere penalty of the time constants tried, −2 ln units.
pub fn penalty() -> f64 {
    2.0 * (TAUS_H.len() as f64).ln()
}

/// The warm-up as a candidate of a diagnosis rung, on the evidence scale of the catalog's refits:
/// its best time constant, the model with it converged. `None` when a warm-up is in the model
/// already, the run is too short, or it gains nothing.
pub fn candidate(
    prep: &Prepared,
    effects: &[&dyn Effect],
    id: &Identification,
    cfg: &DiagnoseConfig,
) -> Option<Refit> {
    if effects.iter().any(|e| e.name() == "drift-warmup") {
        return None;
    }
    cfg.progress.note(|| "profiling a gyro warm-up".into());
    let fit = profile(prep, effects, &cfg.identify, id)?;
    if fit.evidence_gain <= super::select::MIN_EVIDENCE_GAIN {
        return None;
    }
    let tau_s = fit.value_s;
    // Weighed with a warm-up of its own; the catalog owns the one a rung adopts.
    let warmup = DriftWarmup { tau_s };
    let mut r = refit_effect(prep, (effects, id), &warmup, penalty(), cfg)?;
    r.profiled = Some(Profiled::WarmupTauS(tau_s));
    r.members = fit.members;
    Some(r)
}
