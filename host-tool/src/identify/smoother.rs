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
//! make S = H P⁻ Hᵀ + R singular: a pass then returns a [`SmootherError`] naming the update and
//! its time, never panics. P⁻ itself is never inverted (a parameter held by a zero prior
//! variance is fine).
//!
//! Memory: a record whose nodes fit in [`KEEP_NODES_BYTES`] (a 60-h run at the 60-s period)
//! keeps them from the forward pass for the backward one. A longer one is checkpointed: the
//! forward pass keeps the filter's (m, P) only every ⌈√N⌉ updates; the backward pass recomputes
//! one segment's nodes at a time from its checkpoint, with the same operations on the same
//! inputs, so the results are bit-identical to keeping every node. Node memory is then O(√N)
//! (about 15 MB at 2 M updates) for one more forward pass of work; what grows with N is the
//! output (states and innovations).
//!
//! The algebra is structured, in flat buffers allocated once per pass: Φ is the identity outside
//! the dynamic rows (the angles, Gauss–Markov states), H is zero outside the measured columns,
//! and P is kept exactly symmetric, so a step costs O(nd·n²) instead of dense O(n³) products. The
//! backward pass is the modified Bryson–Frazier form of the RTS smoother (an adjoint vector
//! carried back, see [`run`]): O(n²) per node, no factorisation. Each node's covariance is
//! written once, by its step, where the backward pass reads it (no copies).

use estimator_core::filter::three_rows_times;
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

/// The previous node's time, s, and temperature deviation before update `j` of a pass over
/// `meas` (`temps`: [`temp_devs`]): node 0 is at t = 0 with the first temperature.
pub(crate) fn before(meas: &[Measurement], temps: &[f64], j: usize) -> (f64, f64) {
    match j.checked_sub(1) {
        Some(i) => (meas[i].t_s, temps[i]),
        None => (0.0, temps.first().copied().unwrap_or(0.0)),
    }
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
    /// The start of a noise-free nominal does not have one value per state.
    #[error("the start state has {got} values, the model has {need} states")]
    StartLength {
        /// Values given.
        got: usize,
        /// The model's states.
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
}

/// Everything one forward step computes, in buffers allocated once per pass (a step allocates
/// nothing). Matrices are row-major n×n slices; P⁻ and P (in the caller's buffer) are kept
/// exactly symmetric.
struct Step {
    /// Φ's dynamic rows (`dynamic_states()[r]`, row r at `r·n`); every other row of Φ is the
    /// identity's.
    phi: Vec<f64>,
    /// m − x̄ at the previous node (n).
    dm: Vec<f64>,
    /// Rows `dynamic` of Φ·P (nd × n).
    a: Vec<f64>,
    m_pred: Vec<f64>,
    /// The filter mean after the update (n); its covariance goes to the caller's buffer.
    m: Vec<f64>,
    /// Columns of H that are not zero.
    cols: Vec<usize>,
    /// Rows of U = P⁻Hᵀ, of K = P⁻HᵀS⁻¹ and of U − K·S (n each).
    u: Vec<Vector3<f64>>,
    k: Vec<Vector3<f64>>,
    w: Vec<Vector3<f64>>,
    /// K's and W's three columns as contiguous vectors (the Joseph update runs along them).
    k_cols: [Vec<f64>; 3],
    w_cols: [Vec<f64>; 3],
    nu: Vector3<f64>,
    chol_l: Matrix3<f64>,
    s: Matrix3<f64>,
    s_inv: Matrix3<f64>,
    whitened: Vector3<f64>,
    /// S⁻¹ν, the update's term of the backward pass's adjoint.
    s_inv_nu: Vector3<f64>,
    predicted: [f64; 3],
}

impl Step {
    fn new(n: usize, nd: usize) -> Self {
        Step {
            // Whole groups of three rows (the padding rows stay zero): `Forward::step` forms
            // Φ_D P three rows at a time.
            phi: vec![0.0; nd.div_ceil(3) * 3 * n],
            dm: vec![0.0; n],
            a: vec![0.0; nd.div_ceil(3) * 3 * n],
            m_pred: vec![0.0; n],
            m: vec![0.0; n],
            cols: Vec::with_capacity(n),
            u: vec![Vector3::zeros(); n],
            k: vec![Vector3::zeros(); n],
            w: vec![Vector3::zeros(); n],
            k_cols: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
            w_cols: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
            nu: Vector3::zeros(),
            chol_l: Matrix3::zeros(),
            s: Matrix3::zeros(),
            s_inv: Matrix3::zeros(),
            whitened: Vector3::zeros(),
            s_inv_nu: Vector3::zeros(),
            predicted: [0.0; 3],
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).fold(0.0, |acc, (x, y)| acc + x * y)
}

/// The trajectory a pass is linearised about.
enum Nominal<'a> {
    /// Given: one state per node.
    Given(&'a [DVector<f64>]),
    /// The model's own noise-free trajectory from a start, propagated by the steps themselves
    /// (the propagation a step does anyway gives the next node): the current node's state.
    NoiseFree(Vec<f64>),
}

/// What update j takes from the model about the nominal: the nominal propagated over the
/// interval (`f`), Φ's dynamic rows and Q (`tr`), and H's columns and h at the next node. None
/// of it depends on the filter, so for a given nominal [`for_each_linearisation`] computes it
/// ahead, on another core, while the filter steps (the same calls on the same inputs: the same
/// bits).
struct Linearisation<const CAP: usize> {
    /// The nominal at node j, where the interval starts.
    xbar_prev: [f64; CAP],
    f: [f64; CAP],
    tr: Transition<CAP>,
    hcols: [Vector3<f64>; CAP],
    h_at_nominal: Vector3<f64>,
}

impl<const CAP: usize> Default for Linearisation<CAP> {
    fn default() -> Self {
        Linearisation {
            xbar_prev: [0.0; CAP],
            f: [0.0; CAP],
            tr: Transition::default(),
            hcols: [Vector3::zeros(); CAP],
            h_at_nominal: Vector3::zeros(),
        }
    }
}

/// Updates per chunk that the linearising thread hands to the filter: a sixteenth of the pass,
/// at least 64 and at most 512 (0.1–0.9 MB). Each hand-off can wake the other thread; chunks of
/// 64 on the 60-h run took four times the context switches and ~5 % more CPU time than chunks of
/// 225, and a shorter pass still overlaps.
fn linearise_chunk(updates: usize) -> usize {
    (updates / 16).clamp(64, 512)
}
/// Fewest updates for which the linearisation runs on a thread of its own.
const LINEARISE_AHEAD_MIN: usize = 256;

/// The fixed inputs of a pass and the forward step, with the core's scratch sized `CAP` (≥ the
/// model's states; [`run`] picks the smallest of a few sizes: the core clears its scratch whole).
struct Forward<'a, 'm, const CAP: usize> {
    model: &'a Model<'m>,
    meas: &'a [Measurement],
    /// The given nominal (one node per measurement and one at t = 0); `None`: the noise-free
    /// trajectory, which [`Linearisations`] carries from node to node.
    given: Option<&'a [DVector<f64>]>,
    temps: Vec<f64>,
}

impl<'a, 'm, const CAP: usize> Forward<'a, 'm, CAP> {
    fn new(
        model: &'a Model<'m>,
        meas: &'a [Measurement],
        nominal: &Nominal<'a>,
    ) -> Result<Self, SmootherError> {
        let n = model.dim();
        if n > CAP {
            return Err(SmootherError::TooManyStates { n });
        }
        let given = match nominal {
            Nominal::Given(v) => Some(*v),
            Nominal::NoiseFree(_) => None,
        };
        let nodes = given.map_or(meas.len() + 1, <[_]>::len);
        if nodes != meas.len() + 1 {
            return Err(SmootherError::NominalLength {
                got: nodes,
                need: meas.len() + 1,
            });
        }
        Ok(Forward {
            model,
            meas,
            given,
            temps: temp_devs(meas),
        })
    }

    /// Previous node's time, s, and temperature deviation before update `j`.
    fn before(&self, j: usize) -> (f64, f64) {
        before(self.meas, &self.temps, j)
    }

    /// The model about the nominal for update `j`, from the nominal at node `j` (`lin.xbar_prev`).
    fn linearise(&self, j: usize, lin: &mut Linearisation<CAP>) {
        let model = self.model;
        let n = model.dim();
        let z = &self.meas[j];
        let (t_prev, temp_prev) = self.before(j);
        lin.f[..n].copy_from_slice(&lin.xbar_prev[..n]);
        propagate(
            model,
            &mut lin.f[..n],
            t_prev,
            z.t_s - t_prev,
            temp_prev,
            self.temps[j],
            &mut lin.tr,
        );
        let xbar = match self.given {
            Some(v) => v[j + 1].as_slice(),
            None => &lin.f[..n],
        };
        lin.h_at_nominal =
            model.measurement(xbar, z.t_s, self.temps[j], z.time_var_s2, &mut lin.hcols);
    }

    /// Update `j` from the filter's `(m, p)` at node `j` to node `j + 1`, with the model
    /// linearised about the nominal by [`Forward::linearise`]: the mean and the update's
    /// factors into `st`, the covariance into `p_out` (n×n, row-major, written whole: first P⁻,
    /// then P⁺ over it in place). Deterministic: the backward pass recomputes segments with it
    /// and gets the same bits.
    ///
    /// Structured: Φ differs from I only in the dynamic rows and H is zero outside a few
    /// columns, so Φ P Φᵀ costs nd·n² and the Joseph update 9 products per entry of one
    /// triangle, instead of dense n³ products.
    #[allow(clippy::too_many_arguments)]
    fn step(
        &self,
        j: usize,
        lin: &Linearisation<CAP>,
        m_prev: &[f64],
        p_prev: &[f64],
        st: &mut Step,
        p_out: &mut [f64],
    ) -> Result<(), SmootherError> {
        #[cfg(target_arch = "x86_64")]
        if estimator_core::cpu::has_avx2() {
            // SAFETY: `step_avx2` needs AVX2, which the CPU was just found to have.
            return unsafe { self.step_avx2(j, lin, m_prev, p_prev, st, p_out) };
        }
        self.step_body(j, lin, m_prev, p_prev, st, p_out)
    }

    /// [`Forward::step`] compiled for AVX2 ([`estimator_core::cpu`]): the same bits, the
    /// identification's forward passes ~10 % faster.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    fn step_avx2(
        &self,
        j: usize,
        lin: &Linearisation<CAP>,
        m_prev: &[f64],
        p_prev: &[f64],
        st: &mut Step,
        p_out: &mut [f64],
    ) -> Result<(), SmootherError> {
        self.step_body(j, lin, m_prev, p_prev, st, p_out)
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)] // into both builds of `step`
    fn step_body(
        &self,
        j: usize,
        lin: &Linearisation<CAP>,
        m_prev: &[f64],
        p_prev: &[f64],
        st: &mut Step,
        p_out: &mut [f64],
    ) -> Result<(), SmootherError> {
        let model = self.model;
        let n = model.dim();
        let dynamic = model.dynamic_states();
        let z = &self.meas[j];
        st.predict_mean(dynamic, lin, m_prev);
        let p_pred = p_out;
        st.predict_covariance(dynamic, lin, p_prev, p_pred);
        let xbar = match self.given {
            Some(v) => v[j + 1].as_slice(),
            None => &lin.f[..n],
        };
        let (predicted, nu) = st.innovation(j, z, lin, xbar)?;
        let (s, s_inv, chol_l) = st.gain(j, z, lin, p_pred, nu)?;
        st.joseph_update(p_pred);
        st.nu = nu;
        st.s_inv_nu = s_inv * nu;
        st.whitened = chol_l.solve_lower_triangular(&nu).unwrap_or(nu);
        st.chol_l = chol_l;
        st.s = s;
        st.s_inv = s_inv;
        st.predicted = predicted;
        Ok(())
    }
}

/// The parts of [`Forward::step`], in its order; inlined into both of its builds.
impl Step {
    /// Φ's dynamic rows from the linearisation, and the predicted mean m⁻ = f(x̄) + Φ (m − x̄).
    #[inline(always)]
    fn predict_mean<const CAP: usize>(
        &mut self,
        dynamic: &[usize],
        lin: &Linearisation<CAP>,
        m_prev: &[f64],
    ) {
        let n = self.m.len();
        let nd = dynamic.len();
        let xbar_prev = &lin.xbar_prev[..n];
        for r in 0..nd {
            self.phi[r * n..(r + 1) * n].copy_from_slice(&lin.tr.rows[r][..n]);
        }
        for i in 0..n {
            self.dm[i] = m_prev[i] - xbar_prev[i];
        }
        for i in 0..n {
            self.m_pred[i] = lin.f[i] + self.dm[i];
        }
        for (r, &d) in dynamic.iter().enumerate() {
            self.m_pred[d] = lin.f[d] + dot(&self.phi[r * n..(r + 1) * n], &self.dm);
        }
    }

    /// P⁻ = Φ P Φᵀ + Q into `p_pred`. With A = rows `dynamic` of Φ P (= columns of P Φᵀ, P
    /// symmetric): P⁻ is P outside the dynamic rows and columns, A there, and A Φ_Dᵀ + Q where
    /// both are dynamic (symmetrised).
    #[inline(always)]
    fn predict_covariance<const CAP: usize>(
        &mut self,
        dynamic: &[usize],
        lin: &Linearisation<CAP>,
        p_prev: &[f64],
        p_pred: &mut [f64],
    ) {
        let n = self.m.len();
        // A = Φ_D P three rows at a time (the core's kernel: the sums of a block of columns
        // in registers; an axpy per row and state was a third of this step in loop overhead).
        for (f, a) in self
            .phi
            .chunks_exact(3 * n)
            .zip(self.a.chunks_exact_mut(3 * n))
        {
            let (a0, rest) = a.split_at_mut(n);
            let (a1, a2) = rest.split_at_mut(n);
            let f = [&f[..n], &f[n..2 * n], &f[2 * n..]];
            three_rows_times(f, p_prev, n, [a0, a1, a2]);
        }
        p_pred.copy_from_slice(&p_prev[..n * n]);
        for (r, &d) in dynamic.iter().enumerate() {
            for c in 0..n {
                let v = self.a[r * n + c];
                p_pred[d * n + c] = v;
                p_pred[c * n + d] = v;
            }
        }
        for (r, &d) in dynamic.iter().enumerate() {
            for (s, &e) in dynamic.iter().enumerate().skip(r) {
                let ar = &self.a[r * n..(r + 1) * n];
                let as_ = &self.a[s * n..(s + 1) * n];
                let v = 0.5
                    * (dot(ar, &self.phi[s * n..(s + 1) * n])
                        + dot(as_, &self.phi[r * n..(r + 1) * n]))
                    + 0.5 * (lin.tr.q[r][s] + lin.tr.q[s][r]);
                p_pred[d * n + e] = v;
                p_pred[e * n + d] = v;
            }
        }
    }

    /// H's non-zero columns, the prediction h(x̄) + H (m⁻ − x̄) of measurement `z` (update `j`)
    /// and the innovation ν; an error when ν is not finite.
    #[inline(always)]
    fn innovation<const CAP: usize>(
        &mut self,
        j: usize,
        z: &Measurement,
        lin: &Linearisation<CAP>,
        xbar: &[f64],
    ) -> Result<([f64; 3], Vector3<f64>), SmootherError> {
        let n = self.m.len();
        let predicted_at_nominal = lin.h_at_nominal;
        self.cols.clear();
        self.cols
            .extend((0..n).filter(|&c| lin.hcols[c] != Vector3::zeros()));
        let mut hdx = Vector3::zeros();
        for &c in &self.cols {
            hdx += lin.hcols[c] * (self.m_pred[c] - xbar[c]);
        }
        let predicted = predicted_at_nominal + hdx;
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
        Ok((predicted, nu))
    }

    /// U = P⁻ Hᵀ, S = H U + R (symmetrised), its Cholesky factor, the gain K = U S⁻¹,
    /// W = U − K S and the updated mean m = m⁻ + K ν; returns (S, S⁻¹, L). An error when S is
    /// not finite or not positive definite (bad data, see the module's doc).
    #[inline(always)]
    #[allow(clippy::type_complexity)]
    fn gain<const CAP: usize>(
        &mut self,
        j: usize,
        z: &Measurement,
        lin: &Linearisation<CAP>,
        p_pred: &[f64],
        nu: Vector3<f64>,
    ) -> Result<(Matrix3<f64>, Matrix3<f64>, Matrix3<f64>), SmootherError> {
        let n = self.m.len();
        // U = P⁻ Hᵀ (row i: Σ_c P⁻[i, c] h_c), S = H U + R.
        for i in 0..n {
            let row = &p_pred[i * n..(i + 1) * n];
            let mut acc = Vector3::zeros();
            for &c in &self.cols {
                acc += lin.hcols[c] * row[c];
            }
            self.u[i] = acc;
        }
        let mut s_dyn = Matrix3::from_diagonal(&Vector3::from(z.variance));
        for &c in &self.cols {
            s_dyn += lin.hcols[c] * self.u[c].transpose();
        }
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
        let s_inv_t = s_inv.transpose();
        for i in 0..n {
            self.k[i] = s_inv_t * self.u[i];
            self.w[i] = self.u[i] - s * self.k[i];
            self.m[i] = self.m_pred[i] + self.k[i].dot(&nu);
            for a in 0..3 {
                self.k_cols[a][i] = self.k[i][a];
                self.w_cols[a][i] = self.w[i][a];
            }
        }
        Ok((s, s_inv, chol_l))
    }

    /// The Joseph update of P⁻ into P, in place:
    /// P = (I − KH) P⁻ (I − KH)ᵀ + K R Kᵀ = P⁻ − K Uᵀ − U Kᵀ + K S Kᵀ (S = H U + R)
    ///   = P⁻ − K Wᵀ − U Kᵀ with W = U − K S (valid for any gain, as the Joseph form is).
    #[inline(always)]
    fn joseph_update(&self, p: &mut [f64]) {
        let n = self.m.len();
        // The upper triangle row by row (entry (i, jj ≥ i) reads only itself), then mirrored
        // into the lower one. Along a row the entries are Kᵢ·Wⱼ + Uᵢ·Kⱼ over contiguous
        // columns of K and W (the products and sums of the two 3-vector dot products, in
        // their order).
        let ([kx, ky, kz], [wx, wy, wz]) = (&self.k_cols, &self.w_cols);
        for i in 0..n {
            let (ki, ui) = (self.k[i], self.u[i]);
            let row = &mut p[i * n + i..(i + 1) * n];
            let len = row.len();
            let (kx, ky, kz) = (&kx[i..i + len], &ky[i..i + len], &kz[i..i + len]);
            let (wx, wy, wz) = (&wx[i..i + len], &wy[i..i + len], &wz[i..i + len]);
            for t in 0..len {
                row[t] -= (ki.x * wx[t] + ki.y * wy[t] + ki.z * wz[t])
                    + (ui.x * kx[t] + ui.y * ky[t] + ui.z * kz[t]);
            }
        }
        for i in 0..n {
            for jj in i + 1..n {
                p[jj * n + i] = p[i * n + jj];
            }
        }
    }
}

/// The linearisations of a pass in update order: about the given nominal, or along the
/// noise-free trajectory from its start (each interval's propagation gives the next node).
struct Linearisations<'f, 'a, 'm, const CAP: usize> {
    fwd: &'f Forward<'a, 'm, CAP>,
    next: usize,
    /// The noise-free trajectory's node before the next update.
    carried: Vec<f64>,
}

impl<'f, 'a, 'm, const CAP: usize> Linearisations<'f, 'a, 'm, CAP> {
    fn new(fwd: &'f Forward<'a, 'm, CAP>, nominal: &Nominal<'_>) -> Self {
        let carried = match nominal {
            Nominal::NoiseFree(start) => start.clone(),
            Nominal::Given(_) => Vec::new(),
        };
        Linearisations {
            fwd,
            next: 0,
            carried,
        }
    }

    /// The next update's linearisation into `lin`; `false` after the last update.
    fn next_into(&mut self, lin: &mut Linearisation<CAP>) -> bool {
        let (j, fwd) = (self.next, self.fwd);
        if j == fwd.meas.len() {
            return false;
        }
        let n = fwd.model.dim();
        match fwd.given {
            Some(v) => lin.xbar_prev[..n].copy_from_slice(v[j].as_slice()),
            None => lin.xbar_prev[..n].copy_from_slice(&self.carried),
        }
        fwd.linearise(j, lin);
        if fwd.given.is_none() {
            self.carried.copy_from_slice(&lin.f[..n]);
        }
        self.next += 1;
        true
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

/// Node memory below which the forward pass keeps every node for the backward pass instead of
/// checkpointing (no recomputation; the same bits either way). A 60-h run at the 60-s period
/// with the paper's 15 states needs 11 MB (3.0 kB per update).
pub(crate) const KEEP_NODES_BYTES: usize = 32 << 20;

/// Covariances of consecutive nodes in one flat buffer: every node's (`keep`, the backward
/// pass reads them) or two slots used in turn. A step reads node j's slot and writes node j+1's:
/// P is never copied.
struct CovSlots {
    buf: Vec<f64>,
    nn: usize,
    keep: bool,
}

impl CovSlots {
    /// `nodes` slots when `keep`, else two.
    fn new(n: usize, nodes: usize, keep: bool) -> Self {
        let slots = if keep { nodes } else { 2 };
        CovSlots {
            buf: vec![0.0; slots * n * n],
            nn: n * n,
            keep,
        }
    }
    fn slot(&self, j: usize) -> usize {
        if self.keep {
            j
        } else {
            j % 2
        }
    }
    fn get(&self, j: usize) -> &[f64] {
        let s = self.slot(j);
        &self.buf[s * self.nn..(s + 1) * self.nn]
    }
    fn get_mut(&mut self, j: usize) -> &mut [f64] {
        let s = self.slot(j);
        &mut self.buf[s * self.nn..(s + 1) * self.nn]
    }
    /// Node j's covariance to read and node j+1's to write.
    fn pair(&mut self, j: usize) -> (&[f64], &mut [f64]) {
        let (a, b) = (self.slot(j), self.slot(j + 1));
        let nn = self.nn;
        if a < b {
            let (lo, hi) = self.buf.split_at_mut(b * nn);
            (&lo[a * nn..(a + 1) * nn], &mut hi[..nn])
        } else {
            let (lo, hi) = self.buf.split_at_mut(a * nn);
            (&hi[..nn], &mut lo[b * nn..(b + 1) * nn])
        }
    }
}

/// What the backward pass needs of each update j of a segment (j local to it): the filter's
/// mean at node j (its covariance is in the pass's [`CovSlots`]), Φ's dynamic rows, H's
/// columns, K's rows and S⁻¹ν.
struct Nodes {
    n: usize,
    nd: usize,
    m: Vec<f64>,
    phi: Vec<f64>,
    h: Vec<Vector3<f64>>,
    k: Vec<Vector3<f64>>,
    s_inv_nu: Vec<Vector3<f64>>,
}

impl Nodes {
    fn bytes_per_node(n: usize, nd: usize) -> usize {
        (n + n * n + nd * n + 6 * n + 3) * std::mem::size_of::<f64>()
    }
    fn new(n: usize, nd: usize, len: usize) -> Self {
        Nodes {
            n,
            nd,
            m: Vec::with_capacity(len * n),
            phi: Vec::with_capacity(len * nd * n),
            h: Vec::with_capacity(len * n),
            k: Vec::with_capacity(len * n),
            s_inv_nu: Vec::with_capacity(len),
        }
    }
    fn clear(&mut self) {
        self.m.clear();
        self.phi.clear();
        self.h.clear();
        self.k.clear();
        self.s_inv_nu.clear();
    }
    /// Appends update `st` from mean `m` (updates are stored in order from the segment's start).
    fn push(&mut self, m: &[f64], st: &Step, h: &[Vector3<f64>]) {
        self.m.extend_from_slice(m);
        self.phi.extend_from_slice(&st.phi[..self.nd * self.n]);
        self.h.extend_from_slice(&h[..self.n]);
        self.k.extend_from_slice(&st.k);
        self.s_inv_nu.push(st.s_inv_nu);
    }
    /// One step of the backward pass through update `at`: the adjoint λ̂ at node at+1 becomes
    /// λ̂ at node at (modified Bryson–Frazier, see [`run`]), with `w` as scratch.
    fn adjoint_back(&self, at: usize, dynamic: &[usize], lam: &mut [f64], w: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if estimator_core::cpu::has_avx2() {
            // SAFETY: `adjoint_back_avx2` needs AVX2, which the CPU was just found to have.
            return unsafe { self.adjoint_back_avx2(at, dynamic, lam, w) };
        }
        self.adjoint_back_body(at, dynamic, lam, w)
    }

    /// [`Nodes::adjoint_back`] compiled for AVX2 ([`estimator_core::cpu`]): the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn adjoint_back_avx2(&self, at: usize, dynamic: &[usize], lam: &mut [f64], w: &mut [f64]) {
        self.adjoint_back_body(at, dynamic, lam, w)
    }

    #[inline(always)] // into both builds of `adjoint_back`
    fn adjoint_back_body(&self, at: usize, dynamic: &[usize], lam: &mut [f64], w: &mut [f64]) {
        let (n, nd) = (self.n, self.nd);
        let (h, k) = (&self.h[at * n..(at + 1) * n], &self.k[at * n..(at + 1) * n]);
        // λ̃ = λ̂ + Hᵀ (S⁻¹ν − Kᵀ λ̂).
        let kt_lam = k
            .iter()
            .zip(lam.iter())
            .fold(Vector3::zeros(), |acc, (ki, l)| acc + ki * *l);
        let y = self.s_inv_nu[at] - kt_lam;
        for (l, hc) in lam.iter_mut().zip(h) {
            *l += hc.dot(&y);
        }
        // λ̂ = Φᵀ λ̃: identity rows give λ̃ itself, dynamic rows their row times λ̃_d.
        w.copy_from_slice(lam);
        for &d in dynamic {
            w[d] = 0.0;
        }
        let phi = &self.phi[at * nd * n..(at + 1) * nd * n];
        for (r, &d) in dynamic.iter().enumerate() {
            let ld = lam[d];
            for (wc, f) in w.iter_mut().zip(&phi[r * n..(r + 1) * n]) {
                *wc += f * ld;
            }
        }
        lam.copy_from_slice(w);
    }
}

/// Runs the forward filter linearised about `nominal` (node 0 at t = 0, then one per measurement),
/// from prior `x0`, `p0`, and the RTS smoother back. With `smooth = false` only the forward pass
/// (filter covariance at the end = the smoothed covariance of the constant parameters).
///
/// Memory: when every node fits in [`KEEP_NODES_BYTES`] the forward pass keeps them; otherwise
/// the backward pass is checkpointed: the forward pass keeps the filter's (m, P) every ⌈√N⌉
/// updates and the backward pass recomputes one segment's nodes at a time from its checkpoint
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
    let mode = if smooth { Mode::Smooth } else { Mode::Filter };
    run(
        Pass::new(model, meas, Nominal::Given(nominal), x0, p0, mode),
        None::<fn(&StepView<'_>)>,
    )
}

/// [`linearised_pass`] smoothing only where `smooth_if` asks for it, of the filter's final mean
/// and covariance: elsewhere its `states` are the final mean alone (what a Gauss–Newton pass that
/// ends there needs; the backward pass was ~a fifth of a pass's CPU in perf on a 60-h run).
pub fn linearised_pass_smoothing_if(
    model: &Model<'_>,
    meas: &[Measurement],
    nominal: &[DVector<f64>],
    (x0, p0): (&DVector<f64>, &DMatrix<f64>),
    smooth_if: &SmoothIf<'_>,
) -> Result<Smoothed, SmootherError> {
    run(
        Pass {
            smooth_if: Some(smooth_if),
            ..Pass::new(model, meas, Nominal::Given(nominal), x0, p0, Mode::Smooth)
        },
        None::<fn(&StepView<'_>)>,
    )
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
    run(
        Pass::new(model, meas, Nominal::Given(nominal), x0, p0, mode),
        Some(observer),
    )
}

/// [`linearised_pass`] with the checkpointed backward pass whatever the record's length, and the
/// model linearised on the filter's own thread, not ahead on another (tests: it must give the
/// same bits as keeping every node with the linearisation computed ahead).
#[doc(hidden)]
pub fn linearised_pass_checkpointed(
    model: &Model<'_>,
    meas: &[Measurement],
    nominal: &[DVector<f64>],
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
) -> Result<Smoothed, SmootherError> {
    run(
        Pass {
            keep_nodes_bytes: 0,
            linearise_ahead: false,
            ..Pass::new(model, meas, Nominal::Given(nominal), x0, p0, Mode::Smooth)
        },
        None::<fn(&StepView<'_>)>,
    )
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
    run(
        Pass::new(
            model,
            meas,
            Nominal::Given(nominal),
            x0,
            p0,
            Mode::CovarianceOnly,
        ),
        None::<fn(&StepView<'_>)>,
    )
    .map(|s| s.final_cov)
}

/// [`final_covariance`] along the model's noise-free trajectory from `start` (node 0, t = 0):
/// the trajectory is propagated by the pass's own steps, with the same calls and so the same
/// bits as [`crate::identify::nominal_trajectory`] gives, without storing it or propagating it
/// twice. Memory independent of the record's length.
pub fn noise_free_covariance(
    model: &Model<'_>,
    meas: &[Measurement],
    start: &[f64],
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
) -> Result<DMatrix<f64>, SmootherError> {
    if start.len() != model.dim() {
        return Err(SmootherError::StartLength {
            got: start.len(),
            need: model.dim(),
        });
    }
    run(
        Pass::new(
            model,
            meas,
            Nominal::NoiseFree(start.to_vec()),
            x0,
            p0,
            Mode::CovarianceOnly,
        ),
        None::<fn(&StepView<'_>)>,
    )
    .map(|s| s.final_cov)
}

/// One pass's inputs.
struct Pass<'a, 'm> {
    model: &'a Model<'m>,
    meas: &'a [Measurement],
    nominal: Nominal<'a>,
    x0: &'a DVector<f64>,
    p0: &'a DMatrix<f64>,
    mode: Mode,
    /// Node memory up to which every node is kept (else the backward pass is checkpointed).
    keep_nodes_bytes: usize,
    /// Whether a long pass over a given nominal linearises ahead on another core.
    linearise_ahead: bool,
    /// In [`Mode::Smooth`], whether to run the backward pass, asked of the filter's final mean
    /// and covariance (`None`: always); where it says no, the states are the final mean alone.
    smooth_if: Option<&'a SmoothIf<'a>>,
}

/// Whether to smooth, asked of a pass's final mean and covariance
/// ([`linearised_pass_smoothing_if`]).
pub type SmoothIf<'f> = dyn Fn(&[f64], &DMatrix<f64>) -> bool + 'f;

impl<'a, 'm> Pass<'a, 'm> {
    /// A pass keeping its nodes up to [`KEEP_NODES_BYTES`].
    fn new(
        model: &'a Model<'m>,
        meas: &'a [Measurement],
        nominal: Nominal<'a>,
        x0: &'a DVector<f64>,
        p0: &'a DMatrix<f64>,
        mode: Mode,
    ) -> Self {
        Pass {
            model,
            meas,
            nominal,
            x0,
            p0,
            mode,
            keep_nodes_bytes: KEEP_NODES_BYTES,
            linearise_ahead: true,
            smooth_if: None,
        }
    }
}

/// The forward pass, then for [`Mode::Smooth`] the backward pass as the modified
/// Bryson–Frazier smoother (Bierman 1977): with the adjoint λ̂ = 0 at the last node and, back
/// through update j (node j → j+1),
///
///   λ̃ = λ̂ + Hᵀ (S⁻¹ν − Kᵀ λ̂),   λ̂ ← Φᵀ λ̃,   x̂ˢ_j = m_j + P_j λ̂,
///
/// the RTS smoother's result (λ̃ = (P⁻)⁻¹ (x̂ˢ − m⁻) at node j+1, since (P⁻)⁻¹ P⁺ = (I − KH)ᵀ)
/// without inverting P⁻: O(n²) per node and no failure where P⁻ is singular (a parameter
/// held fixed by a zero prior variance).
fn run(
    pass: Pass<'_, '_>,
    observer: Option<impl FnMut(&StepView<'_>)>,
) -> Result<Smoothed, SmootherError> {
    // The same operations on the first n entries whatever the capacity, so the same bits.
    match pass.model.dim() {
        0..=16 => run_cap::<16>(pass, observer),
        17..=32 => run_cap::<32>(pass, observer),
        _ => run_cap::<MAX_STATES>(pass, observer),
    }
}

fn run_cap<const CAP: usize>(
    pass: Pass<'_, '_>,
    mut observer: Option<impl FnMut(&StepView<'_>)>,
) -> Result<Smoothed, SmootherError> {
    let Pass {
        model,
        meas,
        nominal,
        x0,
        p0,
        mode,
        keep_nodes_bytes,
        linearise_ahead,
        smooth_if,
    } = pass;
    let n = model.dim();
    // Only a given nominal has nodes an observer can be shown; the noise-free one is only
    // propagated for the covariance.
    let given: &[DVector<f64>] = match &nominal {
        Nominal::Given(v) => v,
        Nominal::NoiseFree(_) => &[],
    };
    debug_assert!(observer.is_none() || !given.is_empty());
    let fwd = Forward::<CAP>::new(model, meas, &nominal)?;
    let updates = meas.len();
    super::work::count(true, n, updates);
    let mut run = ForwardRun::new(model, meas, x0, p0, mode, updates, keep_nodes_bytes);
    // Dense Φ, H and K for an observer (the score tests), built only when there is one.
    let mut view = observer.as_ref().map(|_| ObserverMats::new(n));
    let visit = |j: usize, lin: &Linearisation<CAP>| -> Result<(), SmootherError> {
        run.step(&fwd, j, lin)?;
        if let (Some(obs), Some(view)) = (observer.as_mut(), view.as_mut()) {
            view.show(obs, &fwd, j, lin, &run.st, given);
        }
        run.keep(j, lin);
        Ok(())
    };
    let ahead = linearise_ahead && updates >= LINEARISE_AHEAD_MIN;
    for_each_linearisation(Linearisations::new(&fwd, &nominal), updates, ahead, visit)?;
    let final_cov = DMatrix::from_row_slice(n, n, run.cov.get(updates));
    if mode == Mode::Smooth {
        run.states = if smooth_if.is_none_or(|wanted| wanted(&run.m, &final_cov)) {
            run.smooth_back(&fwd, given)?
        } else {
            // The smoothed trajectory's last state is the filter's final mean (the backward
            // pass starts there): the same bits.
            vec![DVector::from_column_slice(&run.m)]
        };
    }
    Ok(Smoothed {
        states: run.states,
        final_cov,
        innovations: run.innovations,
    })
}

/// Dense Φ, H and K of one update for an observer (the score tests), in buffers allocated once
/// per pass; the pass itself keeps them structured.
struct ObserverMats {
    phi: DMatrix<f64>,
    h: DMatrix<f64>,
    k: DMatrix<f64>,
}

impl ObserverMats {
    fn new(n: usize) -> Self {
        ObserverMats {
            phi: DMatrix::identity(n, n),
            h: DMatrix::zeros(3, n),
            k: DMatrix::zeros(n, 3),
        }
    }

    /// Shows update `j` (just stepped into `st`) to `obs`, with Φ, H and K made dense.
    fn show<const CAP: usize>(
        &mut self,
        obs: &mut impl FnMut(&StepView<'_>),
        fwd: &Forward<'_, '_, CAP>,
        j: usize,
        lin: &Linearisation<CAP>,
        st: &Step,
        given: &[DVector<f64>],
    ) {
        let n = fwd.model.dim();
        let ObserverMats { phi, h, k } = self;
        for (r, &d) in fwd.model.dynamic_states().iter().enumerate() {
            for c in 0..n {
                phi[(d, c)] = st.phi[r * n + c];
            }
        }
        h.fill(0.0);
        for &c in &st.cols {
            h.set_column(c, &lin.hcols[c]);
        }
        for i in 0..n {
            for a in 0..3 {
                k[(i, a)] = st.k[i][a];
            }
        }
        let z = &fwd.meas[j];
        let (t_prev, temp_prev) = fwd.before(j);
        obs(&StepView {
            j,
            t_prev_s: t_prev,
            t_s: z.t_s,
            temp_prev,
            temp: fwd.temps[j],
            time_var_s2: z.time_var_s2,
            nominal_prev: &given[j],
            nominal: &given[j + 1],
            phi,
            h,
            k,
            nu: st.nu,
            chol_l: st.chol_l,
            s_inv: st.s_inv,
        });
    }
}

/// Calls `visit` with every update's linearisation in order. With `ahead` (a long pass over a
/// given nominal, not inside a rayon pool) another core computes them a chunk ahead while this
/// one steps the filter: the linearisation does not depend on the filter, and the same calls
/// on the same inputs give the same bits.
fn for_each_linearisation<const CAP: usize>(
    mut lins: Linearisations<'_, '_, '_, CAP>,
    updates: usize,
    ahead: bool,
    mut visit: impl FnMut(usize, &Linearisation<CAP>) -> Result<(), SmootherError>,
) -> Result<(), SmootherError> {
    // Not inside a rayon pool (Monte Carlo, the model ladder, the plan): its tasks already
    // use every core, and a thread more per pass would only contend with them.
    if !(ahead && rayon::current_thread_index().is_none()) {
        let mut lin = Box::<Linearisation<CAP>>::default();
        let mut j = 0;
        while lins.next_into(&mut lin) {
            visit(j, &lin)?;
            j += 1;
        }
        return Ok(());
    }
    // Chunks go back to be filled again: no clearing, moving or faulting in of ~1 MB
    // per chunk (that was ~8 % of the process's CPU time). A linearisation overwrites
    // every entry the filter reads.
    // On rayon's pool (this thread is outside it, see above), not on a thread of its
    // own: see `crate::pool`.
    rayon::in_place_scope(|scope| {
        type Chunk<const CAP: usize> = Vec<Linearisation<CAP>>;
        let (tx, rx) = std::sync::mpsc::sync_channel::<(Chunk<CAP>, usize)>(2);
        let (back, returned) = std::sync::mpsc::channel::<Chunk<CAP>>();
        scope.spawn(move |_| loop {
            let size = linearise_chunk(updates);
            let mut chunk = returned.try_recv().unwrap_or_default();
            chunk.resize_with(size, Linearisation::default);
            let mut filled = 0;
            while filled < size && lins.next_into(&mut chunk[filled]) {
                filled += 1;
            }
            if filled == 0 || tx.send((chunk, filled)).is_err() {
                return; // the end, or the filter stopped at an error
            }
        });
        let mut j = 0;
        for (chunk, filled) in rx.iter() {
            for lin in &chunk[..filled] {
                visit(j, lin)?;
                j += 1;
            }
            // The linearising thread may have ended: then the chunk is simply dropped.
            let _ = back.send(chunk);
        }
        Ok::<(), SmootherError>(())
    })
}

/// The filter's state through a pass — its mean, and its covariance at every node or in turn —
/// and what the pass keeps of each update for its output and for the backward pass.
struct ForwardRun<'a> {
    meas: &'a [Measurement],
    mode: Mode,
    updates: usize,
    /// Every node kept for the backward pass (else checkpoints every `seg` updates).
    keep_all: bool,
    seg: usize,
    /// The filter's mean at the current node.
    m: Vec<f64>,
    /// Its covariances (exactly symmetric).
    cov: CovSlots,
    st: Step,
    innovations: Vec<Residual>,
    /// Filtered states ([`Mode::Filter`]) or, after [`ForwardRun::smooth_back`], smoothed ones.
    states: Vec<DVector<f64>>,
    /// Filter (m, P) at nodes 0, seg, 2·seg, … (checkpointed smoothing only).
    checkpoints: Vec<(Vec<f64>, Vec<f64>)>,
    nodes: Nodes,
}

impl<'a> ForwardRun<'a> {
    /// At node 0, from the prior `x0`, `p0` (symmetrised); whether every node is kept follows
    /// from the node memory `keep_nodes_bytes` allows.
    fn new(
        model: &Model<'_>,
        meas: &'a [Measurement],
        x0: &DVector<f64>,
        p0: &DMatrix<f64>,
        mode: Mode,
        updates: usize,
        keep_nodes_bytes: usize,
    ) -> Self {
        debug_assert_eq!(updates, meas.len());
        let n = model.dim();
        let nd = model.dynamic_states().len();
        let keep_all = mode == Mode::Smooth
            && updates.saturating_mul(Nodes::bytes_per_node(n, nd)) <= keep_nodes_bytes;
        let seg = if keep_all {
            updates.max(1)
        } else {
            segment_len(updates)
        };
        let keep_innovations = mode != Mode::CovarianceOnly;
        let innovations = Vec::with_capacity(if keep_innovations { updates } else { 0 });
        let mut states = Vec::new();
        if mode == Mode::Filter {
            states.reserve_exact(updates + 1);
            states.push(x0.clone());
        }
        let m = x0.as_slice().to_vec();
        let mut cov = CovSlots::new(n, updates + 1, keep_all);
        for (k, v) in cov.get_mut(0).iter_mut().enumerate() {
            let (i, j) = (k / n, k % n);
            *v = 0.5 * (p0[(i, j)] + p0[(j, i)]);
        }
        let mut checkpoints: Vec<(Vec<f64>, Vec<f64>)> = Vec::new();
        if mode == Mode::Smooth && !keep_all {
            checkpoints.reserve_exact(updates.div_ceil(seg).max(1));
            checkpoints.push((m.clone(), cov.get(0).to_vec()));
        }
        let nodes = if mode == Mode::Smooth {
            Nodes::new(n, nd, seg.min(updates))
        } else {
            Nodes::new(n, nd, 0)
        };
        ForwardRun {
            meas,
            mode,
            updates,
            keep_all,
            seg,
            m,
            cov,
            st: Step::new(n, nd),
            innovations,
            states,
            checkpoints,
            nodes,
        }
    }

    /// The filter through update `j` (its factors into `st`, the covariance into node j+1's slot).
    fn step<const CAP: usize>(
        &mut self,
        fwd: &Forward<'_, '_, CAP>,
        j: usize,
        lin: &Linearisation<CAP>,
    ) -> Result<(), SmootherError> {
        let (p_prev, p_next) = self.cov.pair(j);
        fwd.step(j, lin, &self.m, p_prev, &mut self.st, p_next)
    }

    /// Keeps what the pass needs of update `j` (just stepped) and moves the mean to node j+1.
    fn keep<const CAP: usize>(&mut self, j: usize, lin: &Linearisation<CAP>) {
        let st = &self.st;
        if self.mode != Mode::CovarianceOnly {
            let z = &self.meas[j];
            self.innovations.push(Residual {
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
        if self.keep_all {
            self.nodes.push(&self.m, &self.st, &lin.hcols);
        }
        std::mem::swap(&mut self.m, &mut self.st.m);
        match self.mode {
            Mode::Filter => self.states.push(DVector::from_column_slice(&self.m)),
            Mode::Smooth
                if !self.keep_all && (j + 1).is_multiple_of(self.seg) && j + 1 < self.updates =>
            {
                self.checkpoints
                    .push((self.m.clone(), self.cov.get(j + 1).to_vec()));
            }
            _ => {}
        }
    }

    /// The backward pass (see [`run`]) from the last node: the smoothed states, node 0 first.
    /// A checkpointed pass recomputes each segment's nodes from its checkpoint first.
    fn smooth_back<const CAP: usize>(
        &mut self,
        fwd: &Forward<'_, '_, CAP>,
        given: &[DVector<f64>],
    ) -> Result<Vec<DVector<f64>>, SmootherError> {
        let n = self.m.len();
        let (updates, seg, keep_all) = (self.updates, self.seg, self.keep_all);
        let dynamic = fwd.model.dynamic_states();
        // Built from the last node back, reversed at the end.
        let mut states = Vec::with_capacity(updates + 1);
        states.push(DVector::from_column_slice(&self.m));
        let mut lam = vec![0.0; n];
        let mut w = vec![0.0; n];
        let mut ms = vec![0.0; n];
        let segments = if keep_all { 1 } else { self.checkpoints.len() };
        // A checkpointed segment's covariances, recomputed from its checkpoint.
        let mut seg_cov = CovSlots::new(n, if keep_all { 0 } else { seg + 1 }, true);
        let mut mc = vec![0.0; n];
        let mut lin_back = Box::<Linearisation<CAP>>::default();
        for sgi in (0..segments).rev() {
            let start = sgi * seg;
            let end = (start + seg).min(updates);
            let (covs, base) = if keep_all {
                (&self.cov, 0)
            } else {
                let (cm, cp) = self.checkpoints.pop().unwrap_or_default();
                mc.copy_from_slice(&cm);
                seg_cov.get_mut(0).copy_from_slice(&cp);
                self.nodes.clear();
                for j in start..end {
                    let (p_prev, p_next) = seg_cov.pair(j - start);
                    // Smoothing is over a given nominal (the public passes).
                    let Some(xbar_prev) = given.get(j) else {
                        return Err(SmootherError::NominalLength {
                            got: given.len(),
                            need: updates + 1,
                        });
                    };
                    lin_back.xbar_prev[..n].copy_from_slice(xbar_prev.as_slice());
                    fwd.linearise(j, &mut lin_back);
                    fwd.step(j, &lin_back, &mc, p_prev, &mut self.st, p_next)?;
                    self.nodes.push(&mc, &self.st, &lin_back.hcols);
                    std::mem::swap(&mut mc, &mut self.st.m);
                }
                (&seg_cov, start)
            };
            for j in (start..end).rev() {
                let at = j - start;
                self.nodes.adjoint_back(at, dynamic, &mut lam, &mut w);
                let pj = covs.get(j - base);
                let mj = &self.nodes.m[at * n..(at + 1) * n];
                // m + P λ, as P's rows times λ's entries: P is exactly symmetric, so these are
                // the sums of row i · λ in the same order (the same bits), without a chain of
                // dependent additions per entry.
                ms.fill(0.0);
                for (k, &l) in lam.iter().enumerate() {
                    for (acc, p) in ms.iter_mut().zip(&pj[k * n..(k + 1) * n]) {
                        *acc += p * l;
                    }
                }
                for (acc, x) in ms.iter_mut().zip(mj) {
                    *acc += x; // addition commutes exactly
                }
                states.push(DVector::from_column_slice(&ms));
            }
        }
        states.reverse();
        Ok(states)
    }
}
