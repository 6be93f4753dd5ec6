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

/// Evaluates the dynamic part of f and `F_D·Φ` at state `x` (full length) and the stage input
/// `Φ_D = y0 + a·k.phidot` (formed column by column from the previous slope), into `k`.
#[allow(clippy::too_many_arguments)]
fn derivative<const CAP: usize>(
    model: &Model<'_>,
    x: &[f64],
    t_s: f64,
    temp_dev_c: f64,
    y0: &[[f64; CAP]; MAX_DYNAMIC],
    a: f64,
    jac: &mut [Vector3<f64>; CAP],
    k: &mut Stage<CAP>,
) {
    let n = model.dim();
    let dynamic = model.dynamic_states();
    let nd = dynamic.len();
    let rate = model.angle_rate(x, t_s, temp_dev_c, jac);
    k.xdot[..ANGLES].copy_from_slice(rate.as_slice());
    // F[0..3][dynamic[r]], the angle rows' entries in the dynamic columns, moved out of `jac`
    // (which keeps F[0..3][c] for the other columns c, zero in the dynamic ones); zero from
    // nd on. And 1/τ of the Gauss–Markov rows (zero for the angles and from nd on).
    let mut f_dd = [Vector3::zeros(); MAX_DYNAMIC];
    for (f, &d) in f_dd.iter_mut().zip(dynamic) {
        *f = core::mem::replace(&mut jac[d], Vector3::zeros());
    }
    let mut inv_tau = [0.0; MAX_DYNAMIC];
    for r in ANGLES..nd {
        inv_tau[r] = 1.0 / model.markov(r).tau_s;
        k.xdot[r] = -x[dynamic[r]] * inv_tau[r];
    }
    // Column c of rows 0..3 of F·Φ, Φ = [[Φ_D], [0 I]]: F[·][c] for a non-dynamic column c
    // (Φ's row there is the identity's), plus Σ_r F[·][dynamic[r]]·Φ_D[r][c], in r order; a
    // Gauss–Markov row r is −Φ_D[r]/τ. One pass over the columns per three dynamic rows (the
    // angles, then the Gauss–Markov rows if any), the sums in registers; each column of the
    // stage input is read before the slope's column overwrites it. The rows from nd on only
    // add zeros (F and 1/τ are zero there).
    const _: () = assert!(MAX_DYNAMIC == 2 * ANGLES);
    let [k0, k1, k2, k3, k4, k5] = &mut k.phidot;
    let (k0, k1, k2) = (&mut k0[..n], &mut k1[..n], &mut k2[..n]);
    let (y_0, y_1, y_2) = (&y0[0][..n], &y0[1][..n], &y0[2][..n]);
    let (f0, f1, f2) = (f_dd[0], f_dd[1], f_dd[2]);
    for c in 0..n {
        let q = [y_0[c] + a * k0[c], y_1[c] + a * k1[c], y_2[c] + a * k2[c]];
        let mut acc = jac[c];
        acc += f0 * q[0];
        acc += f1 * q[1];
        acc += f2 * q[2];
        k0[c] = acc.x;
        k1[c] = acc.y;
        k2[c] = acc.z;
    }
    if nd > ANGLES {
        let (k3, k4, k5) = (&mut k3[..n], &mut k4[..n], &mut k5[..n]);
        let (y_3, y_4, y_5) = (&y0[3][..n], &y0[4][..n], &y0[5][..n]);
        let (f3, f4, f5) = (f_dd[3], f_dd[4], f_dd[5]);
        for c in 0..n {
            let q = [y_3[c] + a * k3[c], y_4[c] + a * k4[c], y_5[c] + a * k5[c]];
            let mut acc = Vector3::new(k0[c], k1[c], k2[c]);
            acc += f3 * q[0];
            acc += f4 * q[1];
            acc += f5 * q[2];
            k0[c] = acc.x;
            k1[c] = acc.y;
            k2[c] = acc.z;
            k3[c] = -q[0] * inv_tau[3];
            k4[c] = -q[1] * inv_tau[4];
            k5[c] = -q[2] * inv_tau[5];
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
            derivative(model, x, t0_s, temp0, &tr.rows, 0.0, &mut jac, &mut k);
            for r in 0..nd {
                x[dynamic[r]] += k.xdot[r] * dt_s;
                for c in 0..n {
                    tr.rows[r][c] += k.phidot[r][c] * dt_s;
                }
            }
        }
        Propagation::Rk4 { max_step_s } => {
            let steps = if dt_s > max_step_s {
                sampling::ceil_usize(dt_s / max_step_s)
            } else {
                1
            };
            let h = dt_s / steps as f64;
            // Stage input xs (Φ's is formed in `derivative`), the current stage's slope k, and
            // the weighted sum of slopes.
            let mut xs = [0.0; CAP];
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
                    // Only the dynamic states and rows differ from the step's start.
                    let a = C[stage] * h;
                    if stage > 0 {
                        for r in 0..nd {
                            xs[dynamic[r]] = x[dynamic[r]] + a * k.xdot[r];
                        }
                    }
                    derivative(
                        model,
                        &xs[..n],
                        ts,
                        temp_at(ts),
                        &tr.rows,
                        a,
                        &mut jac,
                        &mut k,
                    );
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
