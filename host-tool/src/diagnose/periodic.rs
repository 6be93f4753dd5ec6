//! A periodic gyro drift of a period the run must find: `w_i += C_i cos(2πt/P) + S_i sin(2πt/P)`
//! (deg/h) — a thermal or electrical cycle other than the solar day (`drift-daily` fixes
//! P = 24 h): an air-conditioning or heating cycle, a half-day tide of the building. Found like
//! the warm-up ([`super::warmup`]): the six amplitudes enter linearly, so every period is weighed
//! linearised about the current fit, from one replay a stage; P runs over [`PERIODS_H`] and then
//! every ×1.03 within the best cell, and the best is refitted and charged the look-elsewhere
//! penalty 2 ln N of the N coarse periods tried. Outside the catalog a 12-h sine was absorbed by `drift-daily`
//! and the coefficients trusted 7–11σ off (diagnose, 36 h at 1–10 s).

use core::f64::consts::TAU;

use estimator_core::effects::{Context, Effect, Param, Partials};
use estimator_core::units::S_PER_H;
use nalgebra::Vector3;

use super::select::{refit_effect, Profiled, Refit};
use super::DiagnoseConfig;
use crate::identify::{Identification, Prepared};

/// Prior 1σ of each component, deg/h: `drift-daily`'s catalog prior.
pub const PRIOR_SIGMA_DEGPH: f64 = 0.01;
/// Periods tried, h: ×1.25 from 3 h to 2 days (a cycle shorter than a few hours moves the
/// platform too little to be seen); those a run cannot show are dropped ([`shows`]).
pub const PERIODS_H: [f64; 14] = [
    3.0, 3.75, 4.69, 5.86, 7.32, 9.16, 11.4, 14.3, 17.9, 22.4, 27.9, 34.9, 43.7, 54.6,
];
/// The fine grid within a coarse cell: ×1.03, 8 steps each way (1.03⁸ ≈ 1.27): over three cycles
/// a period 1.5 % off leaves the phase 0.3 rad off at the end.
const FINE_RATIO: f64 = 1.03;
const FINE_STEPS: i32 = 8;

pub(crate) const PARAMS: [Param; 6] = [
    param("CXc"),
    param("CXs"),
    param("CYc"),
    param("CYs"),
    param("CZc"),
    param("CZs"),
];

const fn param(name: &'static str) -> Param {
    Param {
        name,
        unit: "deg/h",
        prior_sigma: PRIOR_SIGMA_DEGPH,
    }
}

/// The periodic drift of period `period_s`.
#[derive(Clone, Copy, Debug)]
pub struct DriftPeriodic {
    /// Period, s.
    pub period_s: f64,
}

impl Effect for DriftPeriodic {
    fn name(&self) -> &'static str {
        "drift-periodic"
    }
    fn about(&self) -> &'static str {
        "A periodic gyro drift of a period found in the run (a thermal or electrical cycle other \
         than the solar day): the platform's turn rate swings with it."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let (s, c) = (TAU * ctx.t_s / self.period_s).sin_cos();
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

/// Whether a run of `run_h` hours can show a cycle of `period_h` apart from the catalog: two
/// cycles at least (a single slow swing is a trend: a 60-h run's small trend was taken for a
/// 40-h cycle), and not within 20 % of a day — there the sidereal turn of the platform makes the
/// cycle the drift coefficients themselves (a 12-h sine was fitted as a 23-h cycle of 0.017
/// deg/h, 25× its size), and `drift-daily` stands for the solar day.
fn shows(run_h: f64, period_h: f64) -> bool {
    2.0 * period_h <= run_h && !(19.2..=28.8).contains(&period_h)
}

/// The best period for `id`'s fit ([`super::profile::Fit`], its value P) and the look-elsewhere
/// penalty charged (`None`: the run is too short for two periods of the grid, or every pass
/// failed).
pub fn profile(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &crate::identify::Config,
    id: &Identification,
) -> Option<(super::profile::Fit, f64)> {
    let run_h = prep.measurements.last()?.t_s / S_PER_H;
    let coarse_s: Vec<f64> = PERIODS_H
        .iter()
        .filter(|p| shows(run_h, **p))
        .map(|p| p * S_PER_H)
        .collect();
    if id.trajectory.len() != prep.measurements.len() + 1 || coarse_s.len() < 2 {
        return None;
    }
    let penalty = 2.0 * (coarse_s.len() as f64).ln();
    let grid = super::profile::Grid {
        coarse_s: &coarse_s,
        ratio: FINE_RATIO,
        steps: FINE_STEPS,
        made: Profiled::PeriodS,
        penalty,
    };
    let fit = super::profile::over(prep, effects, cfg, id, &grid, |s| shows(run_h, s / S_PER_H))?;
    Some((fit, penalty))
}

/// The periodic drift as a candidate of a diagnosis rung, on the evidence scale of the catalog's
/// refits: its best period, the model with it converged. `None` when one is in the model
/// already, the run is too short, or it gains nothing.
pub fn candidate(
    prep: &Prepared,
    effects: &[&dyn Effect],
    id: &Identification,
    cfg: &DiagnoseConfig,
) -> Option<Refit> {
    if effects.iter().any(|e| e.name() == "drift-periodic") {
        return None;
    }
    cfg.progress
        .note(|| "profiling a periodic gyro drift".into());
    let (fit, penalty) = profile(prep, effects, &cfg.identify, id)?;
    if fit.evidence_gain <= super::select::MIN_EVIDENCE_GAIN {
        return None;
    }
    // Weighed with one of its own; the catalog owns the one a rung adopts.
    let periodic = DriftPeriodic {
        period_s: fit.value_s,
    };
    let mut r = refit_effect(prep, (effects, id), &periodic, penalty, cfg)?;
    r.profiled = Some(Profiled::PeriodS(fit.value_s));
    r.members = fit.members;
    Some(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    /// The drift and its partials at `p`, time `t_s`.
    fn drift_at(e: &DriftPeriodic, p: &[f64], t_s: f64) -> (Vector3<f64>, Vec<Vector3<f64>>) {
        let ctx = Context {
            t_s,
            specific_force: Vector3::new(0.0, 0.0, 9.8),
            temp_dev_c: 0.0,
            north: Vector3::new(f64::NAN, f64::NAN, f64::NAN),
        };
        let (mut value, mut d_params, mut d_force) = (
            Vector3::zeros(),
            vec![Vector3::zeros(); 6],
            Matrix3::zeros(),
        );
        e.drift(
            p,
            &ctx,
            Partials {
                value: &mut value,
                d_params: &mut d_params,
                d_force: &mut d_force,
            },
        );
        (value, d_params)
    }

    /// The partials are the central differences of the drift (the drift is linear in its
    /// amplitudes, so the differences are exact to rounding: 1e-12 deg/h per unit), and the
    /// drift is the cycle it names: a quarter period on, the cosine term has become the sine's.
    #[test]
    fn the_partials_are_the_drifts_differences() {
        let e = DriftPeriodic {
            period_s: 12.0 * S_PER_H,
        };
        let p = [1e-3, -2e-3, 3e-4, 5e-4, -7e-4, 2e-3];
        for t_s in [0.0, 5000.0, 31_000.0, 200_000.0] {
            let (_, d) = drift_at(&e, &p, t_s);
            for k in 0..6 {
                let (mut hi, mut lo) = (p, p);
                hi[k] += 1e-4;
                lo[k] -= 1e-4;
                let numeric = (drift_at(&e, &hi, t_s).0 - drift_at(&e, &lo, t_s).0) / 2e-4;
                assert!((numeric - d[k]).amax() < 1e-12, "t {t_s} k {k}");
            }
        }
        let (at0, _) = drift_at(&e, &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0);
        let (later, _) = drift_at(&e, &[0.0, 1.0, 0.0, 0.0, 0.0, 0.0], 3.0 * S_PER_H);
        assert!((at0 - later).amax() < 1e-12);
    }

    /// Two cycles at least, and none within 20 % of a day.
    #[test]
    fn a_run_shows_the_cycles_it_holds_twice_away_from_the_day() {
        assert!(shows(36.0, 12.0));
        assert!(!shows(20.0, 12.0));
        assert!(!shows(60.0, 24.0));
        assert!(!shows(60.0, 20.0));
        assert!(shows(60.0, 30.0));
    }
}
