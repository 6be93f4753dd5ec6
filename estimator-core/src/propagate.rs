//! Carrying the state and its transition matrix Φ over one filter period.
//!
//! Only the dynamic states (the platform angles and any Gauss–Markov states) move; every other
//! parameter is constant, so Φ differs from the identity only in the dynamic rows: for the
//! paper's model 3 rows of 15 instead of 15×15. The state is carried by RK4; Φ of each sub-step
//! is exp(h·F) with F at the sub-step's midpoint (one Jacobian per sub-step, f alone at the
//! other three stages), formed by blocks from a 3×3 series ([`propagate`]'s doc has the error).

use nalgebra::{Matrix3, Vector3};

use crate::kinematics::rate_to_euler_yz;
use crate::model::{Model, Propagation, ANGLES, MAX_DYNAMIC};

/// Φ and the discrete process noise Q of one period, restricted to the dynamic states.
#[derive(Clone, Copy, Debug)]
pub struct Transition<const CAP: usize> {
    /// `rows[r][c] = Φ[dynamic[r], c]`; all other rows of Φ are rows of the identity.
    pub rows: [[f64; CAP]; MAX_DYNAMIC],
    /// `q[r][s] = Q[dynamic[r], dynamic[s]]`; Q is zero elsewhere.
    pub q: [[f64; MAX_DYNAMIC]; MAX_DYNAMIC],
}

impl<const CAP: usize> Default for Transition<CAP> {
    fn default() -> Self {
        Transition {
            rows: [[0.0; CAP]; MAX_DYNAMIC],
            q: [[0.0; MAX_DYNAMIC]; MAX_DYNAMIC],
        }
    }
}

impl<const CAP: usize> Transition<CAP> {
    /// Φ as a dense n×n row-major array (tests and the host smoother).
    pub fn phi_entry(&self, model: &Model<'_>, i: usize, j: usize) -> f64 {
        match model.dynamic_states().iter().position(|&d| d == i) {
            Some(r) => self.rows[r][j],
            None => f64::from(u8::from(i == j)),
        }
    }
}

/// The dynamic rows of f at `x`: the angle rates, then the Gauss–Markov states' decay, −x/τ —
/// or, `as_midpoint`, x·(−1/τ) as [`StepExp::at`] forms it (a different last bit: the midpoint
/// stage of [`propagate_state`] must give [`propagate`]'s). `scratch` receives the effects'
/// partials, unused. Out of line: three stages call it.
#[inline(never)]
fn rate<const CAP: usize>(
    model: &Model<'_>,
    x: &[f64],
    (t_s, temp_dev_c): (f64, f64),
    scratch: &mut [Vector3<f64>; CAP],
    as_midpoint: bool,
) -> [f64; MAX_DYNAMIC] {
    let mut xdot = [0.0; MAX_DYNAMIC];
    let rate = model.angle_rate_value(x, t_s, temp_dev_c, scratch);
    xdot[..ANGLES].copy_from_slice(rate.as_slice());
    let dynamic = model.dynamic_states();
    for r in ANGLES..dynamic.len() {
        let tau = model.markov(r).tau_s;
        xdot[r] = if as_midpoint {
            x[dynamic[r]] * (-1.0 / tau)
        } else {
            -x[dynamic[r]] / tau
        };
    }
    xdot
}

/// Gauss–Markov states at most (the dynamic states after the three angles).
const MARKOV: usize = MAX_DYNAMIC - ANGLES;

/// One sub-step's transition over the dynamic states D = (θ, M) (angles, Gauss–Markov
/// states) with F taken at one point (the sub-step's midpoint for RK4): E = exp(h·F_DD) by
/// blocks, and Ψ_θθ = h·φ₁(h·A) = h·Σ_{k≥0} (h·A)^k/(k+1)! (A = F_θθ), which maps F's angle
/// rows in the other columns into Φ (Φ_s = [[E, Ψ·F_DN], [0, I]], and only the angle rows of
/// F_DN are non-zero: a Gauss–Markov rate depends on its own state only).
///
/// A Gauss–Markov state decays as e^{dᵢ·s} within the sub-step (dᵢ = −1/τᵢ; its row of E:
/// e^{dᵢ·h} on the diagonal, exact). Its column in the angle rows, ∫₀ʰ e^{A(h−s)}·bᵢ·e^{dᵢ·s} ds
/// (bᵢ = F_θMᵢ), is taken as the other columns are, with the state at the midpoint:
/// Ψ_θθ·bᵢ·e^{dᵢ·h/2}; relative error (dᵢh)²/24 + |dᵢh|·‖Ah‖/12, second order like the midpoint
/// F itself (|dᵢh| ≤ 1/8: the sub-steps, [`propagate`]).
struct StepExp {
    psi_aa: Matrix3<f64>,
    e_aa: Matrix3<f64>,
    /// E_θMᵢ and E_MᵢMᵢ.
    e_am: [Vector3<f64>; MARKOV],
    e_mm: [f64; MARKOV],
}

impl StepExp {
    /// The dynamic rows of f at `x` and the sub-step's transition from F there. F's angle rows
    /// are left in `jac` (`jac[c]` = F[0..3][c]), zero in the dynamic columns. Ψ_θθ by Horner,
    /// P = I + (h·A/(k+1))·P for k = terms … 1 from P = I, Ψ_θθ = h·P, E_θθ = I + Ψ_θθ·A, with
    /// the terms [`series_terms`] asks for; without `series`, the Euler step: Ψ = h·I,
    /// E = I + h·F.
    #[allow(clippy::too_many_arguments)]
    fn at<const CAP: usize>(
        model: &Model<'_>,
        x: &[f64],
        t_s: f64,
        temp_dev_c: f64,
        jac: &mut [Vector3<f64>; CAP],
        h: f64,
        series: bool,
    ) -> ([f64; MAX_DYNAMIC], Self) {
        let mut xdot = [0.0; MAX_DYNAMIC];
        let rate = model.angle_rate(x, t_s, temp_dev_c, jac);
        xdot[..ANGLES].copy_from_slice(rate.as_slice());
        let a = Matrix3::from_columns(&jac[..ANGLES]);
        jac[..ANGLES].fill(Vector3::zeros());
        let terms = if series { series_terms(&a, h) } else { 0 };
        let mut p = Matrix3::identity();
        for k in (1..=terms).rev() {
            p = horner_step(&a, &p, h / (k + 1) as f64);
        }
        let psi_aa = p * h;
        let mut out = StepExp {
            psi_aa,
            e_aa: Matrix3::identity() + psi_aa * a,
            e_am: [Vector3::zeros(); MARKOV],
            e_mm: [0.0; MARKOV],
        };
        let dynamic = model.dynamic_states();
        for (i, &s) in dynamic[ANGLES..].iter().enumerate() {
            let d = -1.0 / model.markov(ANGLES + i).tau_s;
            xdot[ANGLES + i] = x[s] * d;
            let (mid, end) = if series {
                let mid = libm::exp(0.5 * d * h);
                (mid, mid * mid)
            } else {
                (1.0, 1.0 + d * h)
            };
            out.e_am[i] = psi_aa * core::mem::replace(&mut jac[s], Vector3::zeros()) * mid;
            out.e_mm[i] = end;
        }
        (xdot, out)
    }

    /// Φ ← Φ_s·Φ over the dynamic rows. Φ's other rows are the identity's, so its column c
    /// gains Ψ_θθ·F[0..3][c] directly (`jac`, zero in the dynamic columns).
    #[inline(always)] // into both builds of `Ekf::step`
    fn apply<const CAP: usize>(
        &self,
        tr: &mut Transition<CAP>,
        m: usize,
        n: usize,
        jac: &[Vector3<f64>; CAP],
    ) {
        let [r0, r1, r2, gm @ ..] = &mut tr.rows;
        for c in 0..n {
            let mut v = self.psi_aa * jac[c] + self.e_aa * Vector3::new(r0[c], r1[c], r2[c]);
            for i in 0..m {
                v += self.e_am[i] * gm[i][c];
                gm[i][c] *= self.e_mm[i];
            }
            (r0[c], r1[c], r2[c]) = (v.x, v.y, v.z);
        }
    }
}

/// Terms of the φ₁ series for a remainder below ε/4 relative, from a bound of ρ = ‖h·A‖∞ (at
/// most [`PSI_TERMS`]; six for the paper's 60-s step, where ρ ≈ 4.4e-3 is the Earth's turn in
/// a step).
fn series_terms(a: &Matrix3<f64>, h: f64) -> usize {
    // The sum of all |entries| bounds the largest row sum.
    let rho = h.abs() * a.iter().map(|v| v.abs()).sum::<f64>();
    let mut terms = 0;
    let mut bound = 1.0;
    while terms < PSI_TERMS && bound > f64::EPSILON / 4.0 {
        terms += 1;
        bound *= rho / (terms + 1) as f64;
    }
    terms
}

/// One Horner step of φ₁: I + α·A·P.
fn horner_step(a: &Matrix3<f64>, p: &Matrix3<f64>, alpha: f64) -> Matrix3<f64> {
    Matrix3::identity() + a * p * alpha
}

/// Most terms of the φ₁ series ([`series_terms`]): enough for ρ up to about 3.5.
const PSI_TERMS: usize = 30;

/// Propagates `x` (length `model.dim()`) from `t0_s` over `dt_s` and returns Φ and Q of the
/// interval. Temperature deviation is interpolated linearly from `temp0` to `temp1` (°C).
///
/// RK4 carries the state; Φ of each sub-step is the exponential of F at the sub-step's
/// midpoint (Magnus' first term: the second stage's state and time), so F is evaluated once per
/// sub-step and f alone at the other three stages. Φ then differs from the derivative of the
/// Runge–Kutta map by the Magnus truncation: (h·ν)²/24 + h²·‖[Ḟ, F]‖/12 relative to a column,
/// where ν is the rate at which F changes (for the paper's model the Earth's turn, 7.3e-5
/// rad/s: about 1e-5 at 60 s; a regressor that changes by a fraction ν·h within the sub-step,
/// such as a fast temperature ramp, adds ρ·ν·h/12 with ρ = ‖h·F_DD‖). Second order in h
/// (tests/jacobians.rs). Only the gain and the covariance see it: the state, and with it the
/// predicted measurement and the residuals, keeps RK4's accuracy; a Gauss–Newton fit converges
/// to the same point up to that relative error times its (noise-sized) gradient.
#[inline(always)] // into both builds of `Ekf::step`
pub fn propagate<const CAP: usize>(
    model: &Model<'_>,
    x: &mut [f64],
    t0_s: f64,
    dt_s: f64,
    temp0: f64,
    temp1: f64,
    tr: &mut Transition<CAP>,
) {
    carry::<CAP, true>(model, x, (t0_s, dt_s), (temp0, temp1), tr);
}

/// [`propagate`]'s state alone, bit for bit, without Φ and Q: where only the state is wanted
/// (a trajectory, central differences of the one-step map) F's angle rows, the φ₁ series and
/// Φ's columns were most of a step's work.
pub fn propagate_state<const CAP: usize>(
    model: &Model<'_>,
    x: &mut [f64],
    t0_s: f64,
    dt_s: f64,
    temp0: f64,
    temp1: f64,
) {
    let mut unused = Transition::<CAP>::default();
    carry::<CAP, false>(model, x, (t0_s, dt_s), (temp0, temp1), &mut unused);
}

/// [`propagate`] (`PHI`) or [`propagate_state`]: one body, so the two carry the state by the
/// same operations. Without `PHI` the midpoint stage takes f alone, as [`StepExp::at`] forms it
/// ([`rate`] `as_midpoint`: the same bits).
#[inline(always)]
fn carry<const CAP: usize, const PHI: bool>(
    model: &Model<'_>,
    x: &mut [f64],
    (t0_s, dt_s): (f64, f64),
    (temp0, temp1): (f64, f64),
    tr: &mut Transition<CAP>,
) {
    let n = model.dim();
    let dynamic = model.dynamic_states();
    let nd = dynamic.len();
    if PHI {
        for (r, &d) in dynamic.iter().enumerate() {
            tr.rows[r][..n].iter_mut().for_each(|v| *v = 0.0);
            tr.rows[r][d] = 1.0;
        }
    }
    let theta0 = Vector3::new(x[0], x[1], x[2]);
    let mut jac = [Vector3::zeros(); CAP];
    let temp_at = |t: f64| {
        if dt_s > 0.0 {
            temp0 + (temp1 - temp0) * (t - t0_s) / dt_s
        } else {
            temp1
        }
    };
    match model.propagation() {
        Propagation::Euler => {
            let xdot = if PHI {
                let (xdot, step) = StepExp::at(model, x, t0_s, temp0, &mut jac, dt_s, false);
                step.apply(tr, nd - ANGLES, n, &jac);
                xdot
            } else {
                rate(model, x, (t0_s, temp0), &mut jac, true)
            };
            for r in 0..nd {
                x[dynamic[r]] += xdot[r] * dt_s;
            }
        }
        Propagation::Rk4 { max_step_s } => {
            // Sub-steps of at most `max_step_s`, and of at most τ/8 of the fastest Gauss–Markov
            // state (RK4's accuracy there: 2.5e-7 relative per sub-step; and Φ's, StepExp).
            let mut steps = 1.0_f64.max(dt_s / max_step_s);
            for r in ANGLES..nd {
                steps = steps.max(8.0 * dt_s / model.markov(r).tau_s);
            }
            let steps = if steps > 1.0 {
                sampling::ceil_usize(steps)
            } else {
                1
            };
            let h = dt_s / steps as f64;
            let mut xs = [0.0; CAP];
            xs[..n].copy_from_slice(&x[..n]);
            for s in 0..steps {
                let t = t0_s + s as f64 * h;
                let mid = t + 0.5 * h;
                let k1 = rate(model, &x[..n], (t, temp_at(t)), &mut jac, false);
                for r in 0..nd {
                    xs[dynamic[r]] = x[dynamic[r]] + 0.5 * h * k1[r];
                }
                let temp_mid = temp_at(mid);
                let k2 = if PHI {
                    let (k2, step) = StepExp::at(model, &xs[..n], mid, temp_mid, &mut jac, h, true);
                    step.apply(tr, nd - ANGLES, n, &jac);
                    k2
                } else {
                    rate(model, &xs[..n], (mid, temp_mid), &mut jac, true)
                };
                for r in 0..nd {
                    xs[dynamic[r]] = x[dynamic[r]] + 0.5 * h * k2[r];
                }
                let k3 = rate(model, &xs[..n], (mid, temp_mid), &mut jac, false);
                for r in 0..nd {
                    xs[dynamic[r]] = x[dynamic[r]] + h * k3[r];
                }
                let k4 = rate(model, &xs[..n], (t + h, temp_at(t + h)), &mut jac, false);
                for r in 0..nd {
                    x[dynamic[r]] += h / 6.0 * (k1[r] + 2.0 * (k2[r] + k3[r]) + k4[r]);
                }
            }
        }
    }
    if PHI {
        process_noise(model, theta0, Vector3::new(x[0], x[1], x[2]), dt_s, tr);
    }
}

/// Q of an interval of `dt_s` from attitude `theta0` to `theta1` into `tr`: gyro rate noise
/// mapped to Euler rates through K(θ) at mid-interval; exact discrete variance for the
/// Gauss–Markov states.
#[inline(always)]
fn process_noise<const CAP: usize>(
    model: &Model<'_>,
    theta0: Vector3<f64>,
    theta1: Vector3<f64>,
    dt_s: f64,
    tr: &mut Transition<CAP>,
) {
    let nd = model.dynamic_states().len();
    tr.q = [[0.0; MAX_DYNAMIC]; MAX_DYNAMIC];
    let theta_mid = (theta0 + theta1) * 0.5;
    // K(θ) depends on ty and tz only: two sines and cosines, not a whole attitude.
    let kk = rate_to_euler_yz(
        crate::trig::sincos(theta_mid.y),
        crate::trig::sincos(theta_mid.z),
    );
    let q: Matrix3<f64> = kk * kk.transpose() * (model.arw_rad2ps() * dt_s);
    for i in 0..ANGLES {
        for j in 0..ANGLES {
            tr.q[i][j] = q[(i, j)];
        }
    }
    for r in ANGLES..nd {
        let m = model.markov(r);
        tr.q[r][r] = 0.5 * m.q * m.tau_s * (1.0 - libm::exp(-2.0 * dt_s / m.tau_s));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::{DriftMarkov, Effect, PaperDrift};
    use crate::frames::Site;

    /// A Gauss–Markov state faster than the filter period (τ = 10 s, period 60 s) is carried in
    /// sub-steps of at most τ/8 (48 here): its state decays as exp(−t/τ) (RK4 with h/τ = 1/8
    /// errs by 2.5e-7 per sub-step, 1.2e-5 over the period: tolerance 1e-4; one 60-s step,
    /// h/τ = 6, would multiply it by RK4's R(−6) = +31), and Φ's entry for it is the exact
    /// exponential exp(−6) to rounding (1e-14 relative: e^{−h/τ} per sub-step, 48 products).
    #[test]
    fn a_fast_gauss_markov_state_decays_and_its_transition_is_exact() {
        static FAST: DriftMarkov = DriftMarkov {
            sigma_degph: 0.01,
            tau_h: 10.0 / 3600.0,
        };
        static EFFECTS: [&dyn Effect; 2] = [&PaperDrift, &FAST];
        let model =
            Model::new(Site::new(39.1, None), &EFFECTS, 0.0, Propagation::default()).unwrap();
        let mut x = [0.0; 18];
        x[15..18].copy_from_slice(&[0.01, -0.02, 0.03]);
        let x0 = x;
        let mut tr = Transition::<18>::default();
        propagate(&model, &mut x, 0.0, 60.0, 0.0, 0.0, &mut tr);
        let decay = libm::exp(-6.0);
        for i in 15..18 {
            assert!(
                (x[i] / x0[i] / decay - 1.0).abs() < 1e-4,
                "x[{i}] = {}",
                x[i]
            );
            let phi = tr.phi_entry(&model, i, i);
            assert!((phi / decay - 1.0).abs() < 1e-14, "Φ[{i}][{i}] = {phi}");
        }
    }

    /// The state alone is the state [`propagate`] carries, to the bit: with a Gauss–Markov
    /// state (its own rows, the sub-steps it forces), with a temperature ramp, by RK4 and by
    /// Euler. Every user of `propagate_state` (a trajectory, the knobs' central differences)
    /// relies on that: a difference of the last bit would change their outputs.
    #[test]
    fn the_state_alone_is_propagates_state_bit_for_bit() {
        static SLOW: DriftMarkov = DriftMarkov {
            sigma_degph: 0.01,
            tau_h: 0.004,
        };
        static EFFECTS: [&dyn Effect; 2] = [&PaperDrift, &SLOW];
        for propagation in [Propagation::default(), Propagation::Euler] {
            let model = Model::new(Site::new(39.1, None), &EFFECTS, 1e-9, propagation).unwrap();
            let mut x = [0.0; 18];
            for (i, v) in x.iter_mut().enumerate() {
                *v = 1e-4 * (i as f64 + 1.0).sin();
            }
            let mut y = x;
            let mut tr = Transition::<18>::default();
            for k in 0..50 {
                let t0 = 37.5 + 60.0 * k as f64;
                propagate(&model, &mut x, t0, 60.0, 0.1, 0.4, &mut tr);
                propagate_state::<18>(&model, &mut y, t0, 60.0, 0.1, 0.4);
                let bits = |v: &[f64; 18]| v.map(f64::to_bits);
                assert_eq!(bits(&x), bits(&y), "{propagation:?}, step {k}");
            }
        }
    }
}
