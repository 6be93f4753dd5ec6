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
//!
//! Bad data (swapped or mis-scaled columns, a start far from level, a stuck axis, spikes) can
//! make S = H P⁻ Hᵀ + R or P⁻ singular: a pass then returns a [`SmootherError`] naming the
//! update and its time, never panics.
//!
//! Memory: the backward pass is checkpointed. The forward pass keeps the filter's (m, P) only
//! every ⌈√N⌉ updates; the backward pass recomputes one segment's nodes at a time from its
//! checkpoint, with the same operations on the same inputs, so the results are bit-identical to
//! keeping every node. Node memory is O(√N) (about 15 MB at 2 M updates) for one more forward
//! pass of work; what grows with N is the output (states and innovations).

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

/// What the recording or the nominal did to make a linearised pass impossible.
///
/// Update indices count measurements (filter updates) from 0; times are the measurement's
/// time tag. On good data none of these occur; they point at swapped or mis-scaled columns, a
/// start far from level, a stuck axis, spikes, or a diverged nominal trajectory.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SmootherError {
    /// The model does not fit in the state capacity.
    #[error("the model has {n} states, more than the capacity of {MAX_STATES}")]
    TooManyStates {
        /// Model dimension.
        n: usize,
    },
    /// The nominal trajectory does not have one node at t = 0 plus one per measurement.
    #[error("the nominal trajectory has {got} nodes, need {need} (one at t = 0 and one per measurement)")]
    NominalLength {
        /// Nodes given.
        got: usize,
        /// Nodes needed.
        need: usize,
    },
    /// The innovation is NaN or infinite.
    #[error("update {update} at t = {t_s} s: innovation not finite (measured {measured:?} m/s², predicted {predicted:?} m/s²); a missing or corrupt value in the recording, or a diverged nominal trajectory")]
    InnovationNotFinite {
        /// Update index.
        update: usize,
        /// Measurement time, s.
        t_s: f64,
        /// Measured specific force, m/s².
        measured: [f64; 3],
        /// Predicted specific force, m/s².
        predicted: [f64; 3],
    },
    /// S = H P⁻ Hᵀ + R has no Cholesky factor.
    #[error("update {update} at t = {t_s} s: innovation covariance not positive definite (diagonal {:.3e}, {:.3e}, {:.3e} (m/s²)²); check the recording for swapped or mis-scaled columns, a start far from level, a stuck axis or spikes", .diagonal[0], .diagonal[1], .diagonal[2])]
    InnovationCovariance {
        /// Update index.
        update: usize,
        /// Measurement time, s.
        t_s: f64,
        /// Diagonal of S, (m/s²)².
        diagonal: [f64; 3],
    },
    /// The predicted covariance P⁻ of an update is singular (backward pass).
    #[error("update {update} at t = {t_s} s: predicted covariance not invertible in the backward (smoothing) pass; check the recording for swapped or mis-scaled columns, a start far from level, a stuck axis or spikes")]
    PredictedCovariance {
        /// Update index.
        update: usize,
        /// Measurement time, s.
        t_s: f64,
    },
}

/// Filter quantities of one node, as the backward pass needs them.
struct Node {
    m_pred: DVector<f64>,
    p_pred: DMatrix<f64>,
    m: DVector<f64>,
    p: DMatrix<f64>,
    phi: DMatrix<f64>,
}

/// Everything one forward step computes.
struct Step {
    node: Node,
    h: DMatrix<f64>,
    k: DMatrix<f64>,
    nu: Vector3<f64>,
    chol_l: Matrix3<f64>,
    s: Matrix3<f64>,
    s_inv: Matrix3<f64>,
    whitened: Vector3<f64>,
    predicted: [f64; 3],
}

/// The fixed inputs of a pass and the forward step.
struct Forward<'a, 'm> {
    model: &'a Model<'m>,
    meas: &'a [Measurement],
    nominal: &'a [DVector<f64>],
    temps: Vec<f64>,
    tr: Transition<MAX_STATES>,
    hcols: [Vector3<f64>; MAX_STATES],
}

impl<'a, 'm> Forward<'a, 'm> {
    fn new(
        model: &'a Model<'m>,
        meas: &'a [Measurement],
        nominal: &'a [DVector<f64>],
    ) -> Result<Self, SmootherError> {
        let n = model.dim();
        if n > MAX_STATES {
            return Err(SmootherError::TooManyStates { n });
        }
        if nominal.len() != meas.len() + 1 {
            return Err(SmootherError::NominalLength {
                got: nominal.len(),
                need: meas.len() + 1,
            });
        }
        Ok(Forward {
            model,
            meas,
            nominal,
            temps: temp_devs(meas),
            tr: Transition::default(),
            hcols: [Vector3::zeros(); MAX_STATES],
        })
    }

    /// Previous node's time, s, and temperature deviation before update `j`.
    fn before(&self, j: usize) -> (f64, f64) {
        match j.checked_sub(1) {
            Some(i) => (self.meas[i].t_s, self.temps[i]),
            None => (0.0, self.temps.first().copied().unwrap_or(0.0)),
        }
    }

    /// Update `j` from the filter's `(m, p)` at node `j` to node `j + 1`. Deterministic: the
    /// backward pass recomputes segments with it and gets the same bits.
    fn step(
        &mut self,
        j: usize,
        m_prev: &DVector<f64>,
        p_prev: &DMatrix<f64>,
    ) -> Result<Step, SmootherError> {
        let model = self.model;
        let n = model.dim();
        let z = &self.meas[j];
        let (t_prev, temp_prev) = self.before(j);
        let xbar_prev = &self.nominal[j];
        let mut f = xbar_prev.as_slice().to_vec();
        propagate(
            model,
            &mut f,
            t_prev,
            z.t_s - t_prev,
            temp_prev,
            self.temps[j],
            &mut self.tr,
        );
        let mut phi = DMatrix::identity(n, n);
        let mut q = DMatrix::zeros(n, n);
        let dynamic = model.dynamic_states();
        for (r, &d) in dynamic.iter().enumerate() {
            for c in 0..n {
                phi[(d, c)] = self.tr.rows[r][c];
            }
            for (s, &e) in dynamic.iter().enumerate() {
                q[(d, e)] = self.tr.q[r][s];
            }
        }
        let m_pred = DVector::from_vec(f) + &phi * (m_prev - xbar_prev);
        let p_pred = &phi * p_prev * phi.transpose() + q;
        let xbar = &self.nominal[j + 1];
        let predicted_at_nominal = model.measurement(
            xbar.as_slice(),
            z.t_s,
            self.temps[j],
            z.time_var_s2,
            &mut self.hcols,
        );
        let mut h = DMatrix::zeros(3, n);
        for c in 0..n {
            h.set_column(c, &self.hcols[c]);
        }
        let predicted = predicted_at_nominal + &h * (&m_pred - xbar);
        let predicted = [predicted[0], predicted[1], predicted[2]];
        let nu = Vector3::from(z.specific_force) - Vector3::from(predicted);
        if !nu.iter().all(|v| v.is_finite()) {
            return Err(SmootherError::InnovationNotFinite {
                update: j,
                t_s: z.t_s,
                measured: z.specific_force,
                predicted,
            });
        }
        let pht = &p_pred * h.transpose();
        let s_dyn = &h * &pht + DMatrix::from_diagonal(&DVector::from_row_slice(&z.variance));
        let s = Matrix3::from_fn(|a, b| 0.5 * (s_dyn[(a, b)] + s_dyn[(b, a)]));
        let chol = s
            .iter()
            .all(|v| v.is_finite())
            .then(|| s.cholesky())
            .flatten()
            .ok_or(SmootherError::InnovationCovariance {
                update: j,
                t_s: z.t_s,
                diagonal: [s[(0, 0)], s[(1, 1)], s[(2, 2)]],
            })?;
        let s_inv = chol.inverse();
        let chol_l = chol.l();
        let whitened = chol_l.solve_lower_triangular(&nu).unwrap_or(nu);
        let k = &pht * DMatrix::from_fn(3, 3, |a, b| s_inv[(a, b)]);
        let nu_d = DVector::from_row_slice(nu.as_slice());
        let m = &m_pred + &k * &nu_d;
        let ikh = DMatrix::identity(n, n) - &k * &h;
        let r = DMatrix::from_diagonal(&DVector::from_row_slice(&z.variance));
        let mut p = &ikh * &p_pred * ikh.transpose() + &k * r * k.transpose();
        p = (&p + p.transpose()) * 0.5;
        Ok(Step {
            node: Node {
                m_pred,
                p_pred,
                m,
                p,
                phi,
            },
            h,
            k,
            nu,
            chol_l,
            s,
            s_inv,
            whitened,
            predicted,
        })
    }
}

/// What a pass keeps.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Smoothed states, innovations and the final covariance.
    Smooth,
    /// Filtered states, innovations and the final covariance.
    Filter,
    /// Only the final covariance (states and innovations left empty).
    CovarianceOnly,
}

/// Updates per segment of the checkpointed backward pass: ⌈√N⌉, so that the checkpoints
/// (one filter mean and covariance per segment) and one segment's recomputed nodes both take
/// O(√N) memory.
fn segment_len(updates: usize) -> usize {
    let mut k = (updates as f64).sqrt().ceil() as usize;
    while k.saturating_mul(k) < updates {
        k += 1;
    }
    k.max(1)
}

/// Runs the forward filter linearised about `nominal` (node 0 at t = 0, then one per measurement),
/// from prior `x0`, `p0`, and the RTS smoother back. With `smooth = false` only the forward pass
/// (filter covariance at the end = the smoothed covariance of the constant parameters).
///
/// Memory: the backward pass is checkpointed. The forward pass keeps the filter's (m, P) every
/// ⌈√N⌉ updates; the backward pass recomputes one segment's nodes at a time from its checkpoint
/// (the same operations on the same inputs, so the same bits) — O(√N) node memory for about
/// twice the forward work. What grows with N is the output: the states and the innovations.
pub fn linearised_pass(
    model: &Model<'_>,
    meas: &[Measurement],
    nominal: &[DVector<f64>],
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
    smooth: bool,
) -> Result<Smoothed, SmootherError> {
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
    observer: impl FnMut(&StepView<'_>),
) -> Result<Smoothed, SmootherError> {
    let mode = if smooth { Mode::Smooth } else { Mode::Filter };
    run(model, meas, nominal, x0, p0, mode, observer)
}

/// The filter covariance after the last update of the forward pass linearised about `nominal`
/// (that of [`linearised_pass`] with `smooth = false`), keeping neither states nor innovations:
/// memory independent of the record's length beyond the nominal itself.
pub fn final_covariance(
    model: &Model<'_>,
    meas: &[Measurement],
    nominal: &[DVector<f64>],
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
) -> Result<DMatrix<f64>, SmootherError> {
    run(model, meas, nominal, x0, p0, Mode::CovarianceOnly, |_| {}).map(|s| s.final_cov)
}

fn run(
    model: &Model<'_>,
    meas: &[Measurement],
    nominal: &[DVector<f64>],
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
    mode: Mode,
    mut observer: impl FnMut(&StepView<'_>),
) -> Result<Smoothed, SmootherError> {
    let n = model.dim();
    let mut fwd = Forward::new(model, meas, nominal)?;
    let updates = meas.len();
    let seg = segment_len(updates);
    let keep_innovations = mode != Mode::CovarianceOnly;
    let mut innovations = Vec::with_capacity(if keep_innovations { updates } else { 0 });
    let mut states = Vec::new();
    if mode == Mode::Filter {
        states.reserve_exact(updates + 1);
        states.push(x0.clone());
    }
    // Filter (m, P) at nodes 0, seg, 2·seg, … (smoothing only).
    let mut checkpoints: Vec<(DVector<f64>, DMatrix<f64>)> = Vec::new();
    if mode == Mode::Smooth {
        checkpoints.reserve_exact(updates.div_ceil(seg).max(1));
        checkpoints.push((x0.clone(), p0.clone()));
    }
    let mut m = x0.clone();
    let mut p = p0.clone();
    for j in 0..updates {
        let st = fwd.step(j, &m, &p)?;
        let z = &meas[j];
        let (t_prev, temp_prev) = fwd.before(j);
        observer(&StepView {
            j,
            t_prev_s: t_prev,
            t_s: z.t_s,
            temp_prev,
            temp: fwd.temps[j],
            time_var_s2: z.time_var_s2,
            nominal_prev: &nominal[j],
            nominal: &nominal[j + 1],
            phi: &st.node.phi,
            h: &st.h,
            k: &st.k,
            nu: st.nu,
            chol_l: st.chol_l,
            s_inv: st.s_inv,
        });
        if keep_innovations {
            innovations.push(Residual {
                step: j as u32,
                t_s: z.t_s,
                measured: z.specific_force,
                predicted: st.predicted,
                innovation: st.nu.into(),
                s: st.s.transpose().into(),
                whitened: st.whitened.into(),
                nis: st.nu.dot(&(st.s_inv * st.nu)),
                rejected: false,
            });
        }
        m = st.node.m;
        p = st.node.p;
        match mode {
            Mode::Filter => states.push(m.clone()),
            Mode::Smooth if (j + 1) % seg == 0 && j + 1 < updates => {
                checkpoints.push((m.clone(), p.clone()));
            }
            _ => {}
        }
    }
    if mode == Mode::Smooth {
        states = vec![DVector::zeros(n); updates + 1];
        states[updates] = m.clone();
        let mut ms = m.clone();
        // Per segment: filter (m, P) at its nodes start..end−1, and (m⁻, P⁻, Φ) at start+1..end.
        let mut filtered: Vec<(DVector<f64>, DMatrix<f64>)> = Vec::with_capacity(seg);
        let mut predicted: Vec<Node> = Vec::with_capacity(seg);
        while let Some(checkpoint) = checkpoints.pop() {
            let start = checkpoints.len() * seg;
            let end = (start + seg).min(updates);
            filtered.clear();
            predicted.clear();
            filtered.push(checkpoint);
            for j in start..end {
                let (mj, pj) = &filtered[j - start];
                let st = fwd.step(j, mj, pj)?;
                if j + 1 < end {
                    filtered.push((st.node.m.clone(), st.node.p.clone()));
                }
                predicted.push(st.node);
            }
            for j in (start..end).rev() {
                let (mj, pj) = &filtered[j - start];
                let next = &predicted[j - start];
                // G = P_j Φᵀ (P⁻_{j+1})⁻¹, via a Cholesky solve of P⁻ Gᵀ = Φ P_j.
                let rhs = &next.phi * pj;
                let gt = match next.p_pred.clone().cholesky() {
                    Some(c) => c.solve(&rhs),
                    None => next.p_pred.clone().lu().solve(&rhs).ok_or(
                        SmootherError::PredictedCovariance {
                            update: j,
                            t_s: meas[j].t_s,
                        },
                    )?,
                };
                ms = mj + gt.transpose() * (&ms - &next.m_pred);
                states[j] = ms.clone();
            }
        }
    }
    Ok(Smoothed {
        states,
        final_cov: p,
        innovations,
    })
}
