//! The set-up's knobs (latitude, clock rate, gravity) through the fit's own linearised filter:
//! what [`super::setup`] needs of −2 ln p(y) and of the coefficients about the stated set-up —
//! the gradient, the Gauss–Newton curvature and the coefficients' sensitivity — from one replay
//! of the fit instead of refits at moved set-ups.
//!
//! Moving a knob φ changes the model's one-step map f_j (the Earth rate in the site's frame,
//! the time scale the Earth turns on), its measurement h_j (gravity's size and direction, the
//! time stamp) and, for the latitude, the start's angles in the chart. Through the filter
//! linearised about the fit, the innovations then move by −D_j δφ and the filtered state by
//! Ψ_j δφ, by Friedland's recursion ([`crate::diagnose::score`], with T = I):
//!
//! ```text
//! Γ_j = ∂f_j/∂φ,  H_φ,j = ∂h_j/∂φ      central differences of the core's propagation and
//!                                       measurement on the nominal (the fit's trajectory)
//! Ψ_0 = ∂x_0/∂φ                         the start's angles in the chart
//! Ψ⁻_j = Φ_j Ψ_{j−1} + Γ_j,  D_j = H_j Ψ⁻_j + H_φ,j,  Ψ_j = Ψ⁻_j − K_j D_j
//! ```
//!
//! Whitened (S_j = L_j L_jᵀ, D̃ = L⁻¹D, ν̃ = L⁻¹ν), for the linearised model exactly (its S_j do
//! not depend on φ):
//!
//! ```text
//! −2 ln p(y | δφ) = f0 − 2 sᵀ δφ + δφᵀ I δφ,   s = Σ D̃ᵀ ν̃,   I = Σ D̃ᵀ D̃
//! ```
//!
//! and the constant parameters, whose smoothed estimate is the last filtered one, move by
//! Ψ_N δφ. This is the tangent at the stated set-up of what refits to convergence at ±h give as
//! secants; the two agree to the maps' curvature over h (a latitude prior of 0.3° changes the
//! Earth rate's components by 1e-5 of themselves to second order).

use estimator_core::effects::Effect;
use estimator_core::model::MAX_STATES;
use estimator_core::model::{Model, ANGLES};
use estimator_core::propagate::propagate_state;
use nalgebra::{DMatrix, DVector, Vector3};
use rayon::prelude::*;

use super::setup::{clock_scale, moved_site};
use super::smoother::{
    before, linearised_pass_observed, temp_devs, Smoothed, SmootherError, StepView,
};
use super::{build_model, start_prior, Config, Prepared};
use crate::diagnose::score::{Scratch, Signature, StepJacobians, Tracker};

/// The central differences' half-steps per knob (latitude deg, clock ppm, gravity ppm): small
/// against the maps' curvature (1e-3° is 2e-5 rad), large against rounding (the smallest change
/// they make, a gravity of 1e-5 m/s² on 10 m/s², is 1e10 times its last bit).
pub(crate) const STEP: [f64; 3] = [1e-3, 1.0, 1.0];

/// A knob's central difference: its plus and minus sides (`None`: the knob is held).
type Sides<'m> = Option<(Side<'m>, Side<'m>)>;

/// One side of a central difference: the model with a knob moved and the time scale.
struct Side<'m> {
    model: Model<'m>,
    time_scale: f64,
}

/// An offset of the measurements per unit of a consider parameter at update j, m/s² (the daily
/// tilt of the vertical): a signature column with H_β = the offset and Γ = 0.
pub(crate) type Offset<'a> = Box<dyn Fn(usize) -> Vector3<f64> + Sync + 'a>;

/// The knobs' signature through the linearised filter of `effects` on `prep` about `nominal`
/// (one node at t = 0, then one per measurement), from the prior of `prep`'s start, and that
/// filter's pass. Columns: the three knobs per unit (deg, ppm, ppm; a knob not `live` has a
/// zero column), then one per `offsets`.
pub(crate) fn knob_signature(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    nominal: &[DVector<f64>],
    (live, offsets): ([bool; 3], &[Offset<'_>]),
) -> anyhow::Result<(Smoothed, Signature)> {
    let model = build_model(prep.site, effects, cfg)?;
    let n = model.dim();
    if nominal.len() != prep.measurements.len() + 1 {
        return Err(SmootherError::NominalLength {
            got: nominal.len(),
            need: prep.measurements.len() + 1,
        }
        .into());
    }
    let (x0, p0) = start_prior(&model, prep, &prep.start_sigma());
    let q = 3 + offsets.len();
    let mut psi0 = DMatrix::zeros(n, q);
    let mut sides: Vec<Sides<'_>> = vec![];
    for (k, &on) in live.iter().enumerate() {
        if !on {
            sides.push(None);
            continue;
        }
        let side = |sign: f64| -> anyhow::Result<(Side<'_>, [f64; 3])> {
            let mut d = [0.0; 3];
            d[k] = sign * STEP[k];
            let (site, angles) = moved_site(prep, d);
            let model = build_model(site, effects, cfg)?;
            let time_scale = clock_scale(d[1]);
            Ok((Side { model, time_scale }, angles))
        };
        let ((plus, a_plus), (minus, a_minus)) = (side(1.0)?, side(-1.0)?);
        for i in 0..ANGLES {
            psi0[(i, k)] = (a_plus[i] - a_minus[i]) / (2.0 * STEP[k]);
        }
        sides.push(Some((plus, minus)));
    }
    let jacobians = step_jacobians(&prep.measurements, nominal, &model, (&sides, offsets));
    let mut tracker = Tracker::new(psi0, &model, &[], vec![], None);
    let pass = linearised_pass_observed(
        &model,
        &prep.measurements,
        nominal,
        &x0,
        &p0,
        false,
        |v: &StepView<'_>| {
            let nu_w = v.chol_l.solve_lower_triangular(&v.nu).unwrap_or(v.nu);
            tracker.step(v, &jacobians[v.j], &nu_w);
        },
    )?;
    Ok((pass, tracker.into_signature()))
}

/// Γ_j (n × q) and H_β,j (3 × q) of every update: the knobs' by central differences over
/// `sides` (per knob, the moved model's plus and minus sides), then the `offsets`; on every
/// core: they depend on the nominal and the time stamps alone, not on the filter.
fn step_jacobians(
    meas: &[estimator_core::Measurement],
    nominal: &[DVector<f64>],
    model: &Model<'_>,
    (sides, offsets): (&[Sides<'_>], &[Offset<'_>]),
) -> Vec<StepJacobians> {
    let n = model.dim();
    let q = 3 + offsets.len();
    let temps = temp_devs(meas);
    let dynamic = model.dynamic_states();
    (0..meas.len())
        .into_par_iter()
        .map_init(Scratch::default, |scratch, j| {
            let (t_prev, temp_prev) = before(meas, &temps, j);
            let z = &meas[j];
            let mut at = |side: &Side<'_>| -> (Vec<f64>, Vector3<f64>) {
                let c = side.time_scale;
                let mut x = nominal[j].as_slice().to_vec();
                propagate_state::<MAX_STATES>(
                    &side.model,
                    &mut x,
                    t_prev * c,
                    (z.t_s - t_prev) * c,
                    temp_prev,
                    temps[j],
                );
                let y = side.model.measurement(
                    nominal[j + 1].as_slice(),
                    z.t_s * c,
                    temps[j],
                    z.time_var_s2 * c * c,
                    &mut scratch.cols,
                );
                (x, y)
            };
            let mut gamma = DMatrix::zeros(n, q);
            let mut h_beta = DMatrix::zeros(3, q);
            for (k, s) in sides.iter().enumerate() {
                let Some((plus, minus)) = s else { continue };
                let ((x_plus, y_plus), (x_minus, y_minus)) = (at(plus), at(minus));
                let width = 2.0 * STEP[k];
                for &d in dynamic {
                    gamma[(d, k)] = (x_plus[d] - x_minus[d]) / width;
                }
                for i in 0..3 {
                    h_beta[(i, k)] = (y_plus[i] - y_minus[i]) / width;
                }
            }
            for (c, offset) in offsets.iter().enumerate() {
                h_beta.set_column(3 + c, &offset(j));
            }
            StepJacobians {
                gamma,
                a: DMatrix::identity(q, q),
                h_beta,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::setup::moved;
    use crate::identify::smoother::linearised_pass;
    use crate::identify::{identify, neg2_log_evidence};

    /// The signature's gradient, curvature and the coefficients' sensitivity against central
    /// differences of the linearised filter's −2 ln p(y) and final state at the set-up moved by
    /// ± δ (about the same trajectory, from the moved start), for each knob and for the pair
    /// latitude–gravity, which the data measure together (24 h at 10 s, 21.7°), at δ = one of the
    /// data's 1σ of the knob. The curvature is the Gauss–Newton one, Σ D̃ᵀD̃, which leaves out
    /// the residuals times the second derivatives: on this clean run noise, measured 0.6 % of
    /// the latitude's curvature, 0.1 % of the clock's, 1e-8 of gravity's (it enters linearly),
    /// 0.7 % of the cross term; hence 3 % (a factor or a sign wrong fails by far more). A misfit
    /// makes that term large (gravity 18 ppm off as stated gave the latitude's second
    /// difference 450 times Σ D̃ᵀD̃: −g δ²/2 on the vertical against an 18-ppm residual), and it
    /// is the Gauss–Newton curvature the knobs' posterior wants, not the misfit's. The
    /// sensitivities are linear in the residuals: 1 % of the column's largest.
    #[test]
    fn the_signature_is_the_linearised_filters_response_to_the_set_up() {
        let mut sc = crate::simulate::Scenario::paper();
        sc.hours = 24.0;
        sc.rate_s = 10.0;
        sc.latitude_deg = 21.7;
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let effects = [crate::catalog::paper()];
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let (_, sig) =
            knob_signature(&prep, &effects, &cfg, &id.trajectory, ([true; 3], &[])).unwrap();
        let pass = |d: [f64; 3]| {
            let p = moved(&prep, d);
            let m = build_model(p.site, &effects, &cfg).unwrap();
            let (x0, p0) = start_prior(&m, &p, &p.start_sigma());
            let s = linearised_pass(&m, &p.measurements, &id.trajectory, &x0, &p0, false).unwrap();
            (
                neg2_log_evidence(&s.innovations),
                s.states.last().unwrap().clone(),
            )
        };
        let (f0, _) = pass([0.0; 3]);
        let n = model.dim();
        for k in 0..3 {
            let delta = (0.5 / sig.info[(k, k)]).sqrt();
            let mut d = [0.0; 3];
            d[k] = delta;
            let (fp, xp) = pass(d);
            d[k] = -delta;
            let (fm, xm) = pass(d);
            let grad = (fp - fm) / (2.0 * delta);
            let curv = (fp - 2.0 * f0 + fm) / (delta * delta);
            // The gradient's scale: its spread under the model, √(2·curvature).
            let scale = (2.0 * curv).sqrt();
            let g_sig = -2.0 * sig.score[k];
            assert!(
                (g_sig - grad).abs() < 0.03 * scale.max(grad.abs()),
                "knob {k}: gradient {g_sig:.6e} against {grad:.6e} (scale {scale:.3e})"
            );
            let h_sig = 2.0 * sig.info[(k, k)];
            assert!(
                (h_sig / curv - 1.0).abs() < 0.03,
                "knob {k}: curvature {h_sig:.6e} against {curv:.6e}"
            );
            for i in ANGLES..n {
                let fd = (xp[i] - xm[i]) / (2.0 * delta);
                let s = sig.psi_final[(i, k)];
                let col_scale = (ANGLES..n)
                    .map(|r| ((xp[r] - xm[r]) / (2.0 * delta)).abs())
                    .fold(0.0, f64::max);
                assert!(
                    (s - fd).abs() < 0.01 * col_scale,
                    "knob {k}, state {i}: sensitivity {s:.6e} against {fd:.6e}"
                );
            }
        }
        // The latitude–gravity cross term: f(+,+) − f(+,0) − f(0,+) + f0.
        let (dl, dg) = (
            (0.5 / sig.info[(0, 0)]).sqrt(),
            (0.5 / sig.info[(2, 2)]).sqrt(),
        );
        let cross = (pass([dl, 0.0, dg]).0 - pass([dl, 0.0, 0.0]).0 - pass([0.0, 0.0, dg]).0 + f0)
            / (dl * dg);
        let h_sig = 2.0 * sig.info[(0, 2)];
        let diag = 2.0 * (sig.info[(0, 0)] * sig.info[(2, 2)]).sqrt();
        assert!(
            (h_sig - cross).abs() < 0.03 * diag,
            "latitude–gravity: {h_sig:.6e} against {cross:.6e} (diagonal scale {diag:.3e})"
        );
    }
}
