//! Iterated extended Kalman smoother: Gauss–Newton over the whole record.
//!
//! Each iteration linearises the model about a nominal trajectory x̄ (the previous iteration's
//! smoothed states), runs the Kalman filter of that linear(affine) model forward, and an RTS
//! smoother backward; the smoothed states become the next nominal. Once x̄ is close, the
//! linearisation error vanishes and the result is the maximum-likelihood trajectory and
//! coefficients with their covariance — which is then the Cramér–Rao bound evaluated there,
//! including the gyro random drift (process noise on the angles).
//!
//! All model evaluations (propagation, Φ, Q, h, H) are the core's: the math lives in one place.

use estimator_core::model::{Model, MAX_STATES};
use estimator_core::propagate::{propagate, Transition};
use estimator_core::{Measurement, Residual};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// One smoothing pass's output.
#[derive(Clone, Debug)]
pub struct Smoothed {
    /// Smoothed state at node 0 (t = 0) and at every measurement.
    pub states: Vec<DVector<f64>>,
    /// Smoothed covariance at the last node (the parameters' posterior: they are constant).
    pub final_cov: DMatrix<f64>,
    /// Innovations of the forward pass (linearised about the nominal trajectory).
    pub innovations: Vec<Residual>,
}

/// One step of the forward pass, as an observer sees it (the score tests replay through this).
pub struct StepView<'a> {
    /// Update index.
    pub j: usize,
    /// Previous node's time, s, and this measurement's time.
    pub t_prev_s: f64,
    /// This measurement's time, s.
    pub t_s: f64,
    /// Temperature deviation at the previous node and at this one, °C.
    pub temp_prev: f64,
    /// Temperature deviation at this measurement, °C.
    pub temp: f64,
    /// Spread of the averaged sample times, s².
    pub time_var_s2: f64,
    /// Nominal state at the previous node and at this one.
    pub nominal_prev: &'a DVector<f64>,
    /// Nominal state at this measurement.
    pub nominal: &'a DVector<f64>,
    /// Transition matrix of the interval (n×n).
    pub phi: &'a DMatrix<f64>,
    /// Measurement Jacobian (3×n).
    pub h: &'a DMatrix<f64>,
    /// Kalman gain (n×3).
    pub k: &'a DMatrix<f64>,
    /// Innovation and its covariance's Cholesky factor.
    pub nu: Vector3<f64>,
    /// Lower Cholesky factor of S.
    pub chol_l: Matrix3<f64>,
    /// S⁻¹.
    pub s_inv: Matrix3<f64>,
}

/// Temperature deviations (°C from the first finite temperature) of each measurement; 0 without.
pub fn temp_devs(meas: &[Measurement]) -> Vec<f64> {
    let reference = meas.iter().map(|m| m.temp_c).find(|t| t.is_finite());
    let mut last = 0.0;
    meas.iter()
        .map(|m| {
            if let (Some(r), true) = (reference, m.temp_c.is_finite()) {
                last = m.temp_c - r;
            }
            last
        })
        .collect()
}

/// Node bookkeeping of the forward pass.
struct Node {
    m_pred: DVector<f64>,
    p_pred: DMatrix<f64>,
    m: DVector<f64>,
    p: DMatrix<f64>,
    phi: DMatrix<f64>,
}

/// Runs the forward filter linearised about `nominal` (node 0 at t = 0, then one per measurement),
/// from prior `x0`, `p0`, and the RTS smoother back. With `smooth = false` only the forward pass
/// (filter covariance at the end = the smoothed covariance of the constant parameters).
pub fn linearised_pass(
    model: &Model<'_>,
    meas: &[Measurement],
    nominal: &[DVector<f64>],
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
    smooth: bool,
) -> Smoothed {
    linearised_pass_observed(model, meas, nominal, x0, p0, smooth, |_| {})
}

/// [`linearised_pass`] calling `observer` at every forward step.
pub fn linearised_pass_observed(
    model: &Model<'_>,
    meas: &[Measurement],
    nominal: &[DVector<f64>],
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
    smooth: bool,
    mut observer: impl FnMut(&StepView<'_>),
) -> Smoothed {
    let n = model.dim();
    assert!(n <= MAX_STATES && nominal.len() == meas.len() + 1);
    let temps = temp_devs(meas);
    let mut nodes: Vec<Node> = Vec::with_capacity(meas.len() + 1);
    nodes.push(Node {
        m_pred: x0.clone(),
        p_pred: p0.clone(),
        m: x0.clone(),
        p: p0.clone(),
        phi: DMatrix::identity(n, n),
    });
    let mut innovations = Vec::with_capacity(meas.len());
    let mut tr = Transition::<MAX_STATES>::default();
    let mut hcols = [Vector3::zeros(); MAX_STATES];
    let dynamic = model.dynamic_states();
    let mut t_prev = 0.0;
    let mut temp_prev = temps.first().copied().unwrap_or(0.0);
    for (j, z) in meas.iter().enumerate() {
        let prev = nodes.last().unwrap();
        let xbar_prev = &nominal[j];
        let mut f = xbar_prev.as_slice().to_vec();
        propagate(
            model,
            &mut f,
            t_prev,
            z.t_s - t_prev,
            temp_prev,
            temps[j],
            &mut tr,
        );
        let mut phi = DMatrix::identity(n, n);
        let mut q = DMatrix::zeros(n, n);
        for (r, &d) in dynamic.iter().enumerate() {
            for c in 0..n {
                phi[(d, c)] = tr.rows[r][c];
            }
            for (s, &e) in dynamic.iter().enumerate() {
                q[(d, e)] = tr.q[r][s];
            }
        }
        let m_pred = DVector::from_vec(f) + &phi * (&prev.m - xbar_prev);
        let p_pred = &phi * &prev.p * phi.transpose() + q;
        let xbar = &nominal[j + 1];
        let predicted_at_nominal =
            model.measurement(xbar.as_slice(), z.t_s, temps[j], z.time_var_s2, &mut hcols);
        let mut h = DMatrix::zeros(3, n);
        for c in 0..n {
            h.set_column(c, &hcols[c]);
        }
        let predicted = predicted_at_nominal + &h * (&m_pred - xbar);
        let nu = Vector3::from(z.specific_force)
            - Vector3::new(predicted[0], predicted[1], predicted[2]);
        let pht = &p_pred * h.transpose();
        let s_dyn = &h * &pht + DMatrix::from_diagonal(&DVector::from_row_slice(&z.variance));
        let s = Matrix3::from_fn(|a, b| 0.5 * (s_dyn[(a, b)] + s_dyn[(b, a)]));
        let chol = s
            .cholesky()
            .expect("innovation covariance positive definite");
        let s_inv = chol.inverse();
        let whitened = chol.l().solve_lower_triangular(&nu).unwrap_or(nu);
        let k = &pht * DMatrix::from_fn(3, 3, |a, b| s_inv[(a, b)]);
        let nu_d = DVector::from_row_slice(nu.as_slice());
        let m = &m_pred + &k * &nu_d;
        let ikh = DMatrix::identity(n, n) - &k * &h;
        let r = DMatrix::from_diagonal(&DVector::from_row_slice(&z.variance));
        let mut p = &ikh * &p_pred * ikh.transpose() + &k * r * k.transpose();
        p = (&p + p.transpose()) * 0.5;
        observer(&StepView {
            j,
            t_prev_s: t_prev,
            t_s: z.t_s,
            temp_prev,
            temp: temps[j],
            time_var_s2: z.time_var_s2,
            nominal_prev: xbar_prev,
            nominal: xbar,
            phi: &phi,
            h: &h,
            k: &k,
            nu,
            chol_l: chol.l(),
            s_inv,
        });
        innovations.push(Residual {
            step: j as u32,
            t_s: z.t_s,
            measured: z.specific_force,
            predicted: [predicted[0], predicted[1], predicted[2]],
            innovation: nu.into(),
            s: s.transpose().into(),
            whitened: whitened.into(),
            nis: nu.dot(&(s_inv * nu)),
            rejected: false,
        });
        nodes.push(Node {
            m_pred,
            p_pred,
            m,
            p,
            phi,
        });
        t_prev = z.t_s;
        temp_prev = temps[j];
    }
    let last = nodes.last().unwrap();
    let final_cov = last.p.clone();
    let mut states = vec![DVector::zeros(n); nodes.len()];
    *states.last_mut().unwrap() = last.m.clone();
    if smooth {
        let mut ms = last.m.clone();
        for j in (0..nodes.len() - 1).rev() {
            let next = &nodes[j + 1];
            // G = P_j Φᵀ (P⁻_{j+1})⁻¹, via a Cholesky solve of P⁻ Gᵀ = Φ P_j.
            let rhs = &next.phi * &nodes[j].p;
            let gt = match next.p_pred.clone().cholesky() {
                Some(c) => c.solve(&rhs),
                None => next
                    .p_pred
                    .clone()
                    .lu()
                    .solve(&rhs)
                    .expect("predicted covariance invertible"),
            };
            ms = &nodes[j].m + gt.transpose() * (&ms - &next.m_pred);
            states[j] = ms.clone();
        }
    } else {
        for (s, node) in states.iter_mut().zip(&nodes) {
            *s = node.m.clone();
        }
    }
    Smoothed {
        states,
        final_cov,
        innovations,
    }
}
