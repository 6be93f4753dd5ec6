//! Carrying the state and its transition matrix Φ over one filter period.
//!
//! Only the dynamic states (the platform angles and any Gauss–Markov states) move; every other
//! parameter is constant, so Φ differs from the identity only in the dynamic rows. We integrate
//! just those rows: `dΦ_D/dt = F_D·Φ` with the non-dynamic rows of Φ equal to the identity. For
//! the paper's model that is 3 rows of 15 instead of 15×15, which is what makes a step cheap.

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

/// Scratch space for one derivative evaluation.
struct Stage<const CAP: usize> {
    xdot: [f64; MAX_DYNAMIC],
    phidot: [[f64; CAP]; MAX_DYNAMIC],
}

/// Evaluates the dynamic part of f and `F_D·Φ` at state `x` (full length) and `phi`.
fn derivative<const CAP: usize>(
    model: &Model<'_>,
    x: &[f64],
    t_s: f64,
    temp_dev_c: f64,
    phi: &[[f64; CAP]; MAX_DYNAMIC],
    jac: &mut [Vector3<f64>; CAP],
    out: &mut Stage<CAP>,
) {
    let n = model.dim();
    let dynamic = model.dynamic_states();
    let rate = model.angle_rate(x, t_s, temp_dev_c, jac);
    out.xdot[..ANGLES].copy_from_slice(rate.as_slice());
    // F[0..3][dynamic[r]], the angle rows' entries in the dynamic columns, moved out of `jac`
    // (which keeps F[0..3][c] for the other columns c, zero in the dynamic ones).
    let nd = dynamic.len();
    let mut f_dd = [Vector3::zeros(); MAX_DYNAMIC];
    for (f, &d) in f_dd.iter_mut().zip(dynamic) {
        *f = core::mem::replace(&mut jac[d], Vector3::zeros());
    }
    // Column c of rows 0..3 of F·Φ, Φ = [[Φ_D], [0 I]]: F[·][c] for a non-dynamic column c
    // (Φ's row there is the identity's), plus Σ_r F[·][dynamic[r]]·Φ_D[r][c], in r order.
    // One pass over the columns per three dynamic rows, the sums in registers (F is zero in
    // `f_dd` from nd on, so the rows of `phi` from nd on only add zeros).
    const _: () = assert!(MAX_DYNAMIC % 3 == 0);
    let [p0, p1, p2, ..] = &mut out.phidot;
    let (p0, p1, p2) = (&mut p0[..n], &mut p1[..n], &mut p2[..n]);
    for r0 in (0..nd).step_by(3) {
        let (f0, f1, f2) = (f_dd[r0], f_dd[r0 + 1], f_dd[r0 + 2]);
        let (q0, q1, q2) = (&phi[r0][..n], &phi[r0 + 1][..n], &phi[r0 + 2][..n]);
        for c in 0..n {
            let mut acc = if r0 == 0 {
                jac[c]
            } else {
                Vector3::new(p0[c], p1[c], p2[c])
            };
            acc += f0 * q0[c];
            acc += f1 * q1[c];
            acc += f2 * q2[c];
            p0[c] = acc.x;
            p1[c] = acc.y;
            p2[c] = acc.z;
        }
    }
    for r in ANGLES..dynamic.len() {
        let inv_tau = 1.0 / model.markov(r).tau_s;
        out.xdot[r] = -x[dynamic[r]] * inv_tau;
        for (v, p) in out.phidot[r][..n].iter_mut().zip(&phi[r][..n]) {
            *v = -p * inv_tau;
        }
    }
}

/// Propagates `x` (length `model.dim()`) from `t0_s` over `dt_s` and returns Φ and Q of the
/// interval. Temperature deviation is interpolated linearly from `temp0` to `temp1` (°C).
pub fn propagate<const CAP: usize>(
    model: &Model<'_>,
    x: &mut [f64],
    t0_s: f64,
    dt_s: f64,
    temp0: f64,
    temp1: f64,
    tr: &mut Transition<CAP>,
) {
    let n = model.dim();
    let dynamic = model.dynamic_states();
    let nd = dynamic.len();
    for (r, &d) in dynamic.iter().enumerate() {
        tr.rows[r][..n].iter_mut().for_each(|v| *v = 0.0);
        tr.rows[r][d] = 1.0;
    }
    let theta0 = Vector3::new(x[0], x[1], x[2]);
    let mut jac = [Vector3::zeros(); CAP];
    let mut k = Stage {
        xdot: [0.0; MAX_DYNAMIC],
        phidot: [[0.0; CAP]; MAX_DYNAMIC],
    };
    let temp_at = |t: f64| {
        if dt_s > 0.0 {
            temp0 + (temp1 - temp0) * (t - t0_s) / dt_s
        } else {
            temp1
        }
    };
    match model.propagation() {
        Propagation::Euler => {
            derivative(model, x, t0_s, temp0, &tr.rows, &mut jac, &mut k);
            for r in 0..nd {
                x[dynamic[r]] += k.xdot[r] * dt_s;
                for c in 0..n {
                    tr.rows[r][c] += k.phidot[r][c] * dt_s;
                }
            }
        }
        Propagation::Rk4 { max_step_s } => {
            let steps = if dt_s > max_step_s {
                libm::ceil(dt_s / max_step_s) as usize
            } else {
                1
            };
            let h = dt_s / steps as f64;
            // Stage input (xs, phis), the current stage's slope k, and the weighted sum of slopes.
            let mut xs = [0.0; CAP];
            let mut phis = [[0.0; CAP]; MAX_DYNAMIC];
            let mut sum = Stage {
                xdot: [0.0; MAX_DYNAMIC],
                phidot: [[0.0; CAP]; MAX_DYNAMIC],
            };
            const C: [f64; 4] = [0.0, 0.5, 0.5, 1.0];
            const W: [f64; 4] = [1.0, 2.0, 2.0, 1.0];
            for s in 0..steps {
                let t = t0_s + s as f64 * h;
                xs[..n].copy_from_slice(&x[..n]);
                for stage in 0..4 {
                    let ts = t + C[stage] * h;
                    if stage == 0 {
                        derivative(model, &x[..n], ts, temp_at(ts), &tr.rows, &mut jac, &mut k);
                    } else {
                        // Only the dynamic states and rows differ from the step's start.
                        let a = C[stage] * h;
                        for r in 0..nd {
                            xs[dynamic[r]] = x[dynamic[r]] + a * k.xdot[r];
                            let (out, d) = (&mut phis[r][..n], &k.phidot[r][..n]);
                            for ((v, &p), &d) in out.iter_mut().zip(&tr.rows[r][..n]).zip(d) {
                                *v = p + a * d;
                            }
                        }
                        derivative(model, &xs[..n], ts, temp_at(ts), &phis, &mut jac, &mut k);
                    }
                    let w = W[stage];
                    for r in 0..nd {
                        if stage == 0 {
                            sum.xdot[r] = k.xdot[r];
                            sum.phidot[r][..n].copy_from_slice(&k.phidot[r][..n]);
                        } else {
                            sum.xdot[r] += w * k.xdot[r];
                            for (v, d) in sum.phidot[r][..n].iter_mut().zip(&k.phidot[r][..n]) {
                                *v += w * d;
                            }
                        }
                    }
                }
                let w = h / 6.0;
                for r in 0..nd {
                    x[dynamic[r]] += w * sum.xdot[r];
                    for (v, d) in tr.rows[r][..n].iter_mut().zip(&sum.phidot[r][..n]) {
                        *v += w * d;
                    }
                }
            }
        }
    }
    // Process noise: gyro rate noise mapped to Euler rates through K(θ) at mid-interval; exact
    // discrete variance for the Gauss–Markov states.
    for row in tr.q[..nd].iter_mut() {
        row[..nd].iter_mut().for_each(|v| *v = 0.0);
    }
    let theta_mid = (theta0 + Vector3::new(x[0], x[1], x[2])) * 0.5;
    // K(θ) depends on ty and tz only: two sines and cosines, not a whole attitude.
    let kk = rate_to_euler_yz(libm::sincos(theta_mid.y), libm::sincos(theta_mid.z));
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
