//! The extended Kalman filter of the paper (eqs. 11–20), one implementation for firmware and host.
//!
//! Fixed capacity `CAP`, active dimension `model.dim() ≤ CAP`: the state lives in arrays sized at
//! compile time (no heap), while the host chooses the effects — and so the dimension — at run
//! time. The firmware sets `CAP` to exactly its model's size (15 for the paper's).
//!
//! Each step exploits the structure of the model: Φ differs from I only in the dynamic rows
//! (3 angle rows for the paper's model) and H is non-zero only in the measured columns (the angles
//! and accelerometer-effect parameters), so prediction costs O(r·n²) and the Joseph-form update
//! O(3·n²) instead of O(n³).

use nalgebra::{Matrix3, SMatrix, Vector3};

use crate::averaging::Measurement;
use crate::model::{Model, ANGLES, MAX_DYNAMIC};
use crate::propagate::{propagate, Transition};
use crate::residual::Residual;

/// Default prior 1σ of the platform angles at t = 0, rad. θ(0) = 0 by definition (frame 0 is
/// the platform at gyro start), so this only keeps P positive definite: 0.2 arcsec.
pub const ANGLE_PRIOR_SIGMA_RAD: f64 = 1e-6;

/// Why a filter step was refused. The filter state is unchanged after an error.
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(missing_docs)] // fields are named by what they hold: step number, times in s, state index
pub enum FilterError {
    /// The model has more states than the filter's capacity.
    Capacity { needed: usize, capacity: usize },
    /// Initial state or 1σ has the wrong length.
    Dimension { expected: usize, got: usize },
    /// A measurement's time is not after the filter's time.
    TimeNotIncreasing {
        step: u32,
        t_s: f64,
        filter_t_s: f64,
    },
    /// A measurement or its variance is NaN/∞ or the variance is not positive.
    BadMeasurement { step: u32 },
    /// The innovation covariance is not positive definite.
    SingularInnovation { step: u32 },
    /// The covariance lost symmetry/positivity or the state became non-finite at `index`.
    Unhealthy { step: u32, index: usize },
    /// `count` consecutive measurements failed the innovation gate: the filter no longer tracks
    /// the data (a sensor fault or a model break) and refuses to coast on.
    RejectionRun { step: u32, count: u32 },
}

impl core::fmt::Display for FilterError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            FilterError::Capacity { needed, capacity } => {
                write!(f, "model needs {needed} states, filter capacity is {capacity}")
            }
            FilterError::Dimension { expected, got } => write!(f, "expected {expected} values, got {got}"),
            FilterError::TimeNotIncreasing { step, t_s, filter_t_s } => write!(
                f,
                "step {step}: measurement at t = {t_s} s is not after the filter time {filter_t_s} s"
            ),
            FilterError::BadMeasurement { step } => {
                write!(f, "step {step}: measurement or its variance is not finite and positive")
            }
            FilterError::SingularInnovation { step } => {
                write!(f, "step {step}: innovation covariance is not positive definite")
            }
            FilterError::Unhealthy { step, index } => {
                write!(f, "step {step}: covariance or state unhealthy at state {index}")
            }
            FilterError::RejectionRun { step, count } => {
                write!(f, "step {step}: {count} consecutive measurements failed the innovation gate")
            }
        }
    }
}

/// Innovation gate: refuse an update whose NIS exceeds `nis_max`, and fault after
/// `max_run` refusals in a row. Rejections are counted and returned, never silent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gate {
    /// NIS threshold (χ²(3) quantile; e.g. 27.9 is the 1e-5 upper tail).
    pub nis_max: f64,
    /// Consecutive rejections that raise [`FilterError::RejectionRun`].
    pub max_run: u32,
}

impl Gate {
    /// χ²(3) upper 1e-5 quantile with a fault after 10 consecutive rejections.
    pub const DEFAULT: Gate = Gate {
        nis_max: 27.88,
        max_run: 10,
    };
}

/// The EKF: state, covariance and time, over a [`Model`].
#[derive(Clone)]
pub struct Ekf<'m, const CAP: usize> {
    model: Model<'m>,
    gate: Option<Gate>,
    rejected_total: u32,
    rejected_run: u32,
    x: [f64; CAP],
    p: SMatrix<f64, CAP, CAP>,
    t_s: f64,
    temp_ref_c: f64,
    temp_dev_c: f64,
    steps: u32,
}

impl<'m, const CAP: usize> Ekf<'m, CAP> {
    /// A filter at t = 0 with state `x0` and diagonal prior 1σ `sigma0` (both `model.dim()` long).
    pub fn new(model: Model<'m>, x0: &[f64], sigma0: &[f64]) -> Result<Self, FilterError> {
        let n = model.dim();
        if n > CAP {
            return Err(FilterError::Capacity {
                needed: n,
                capacity: CAP,
            });
        }
        for len in [x0.len(), sigma0.len()] {
            if len != n {
                return Err(FilterError::Dimension {
                    expected: n,
                    got: len,
                });
            }
        }
        let mut x = [0.0; CAP];
        x[..n].copy_from_slice(x0);
        let mut p = SMatrix::<f64, CAP, CAP>::zeros();
        for (i, s) in sigma0.iter().enumerate() {
            p[(i, i)] = s * s;
        }
        Ok(Ekf {
            model,
            gate: None,
            rejected_total: 0,
            rejected_run: 0,
            x,
            p,
            t_s: 0.0,
            temp_ref_c: f64::NAN,
            temp_dev_c: 0.0,
            steps: 0,
        })
    }

    /// A filter started as the paper starts it: zero angles and coefficients, each effect's prior 1σ.
    pub fn with_default_prior(model: Model<'m>) -> Result<Self, FilterError> {
        let n = model.dim();
        if n > CAP {
            return Err(FilterError::Capacity {
                needed: n,
                capacity: CAP,
            });
        }
        let mut sigma = [ANGLE_PRIOR_SIGMA_RAD; CAP];
        for (i, s) in sigma.iter_mut().enumerate().take(n).skip(ANGLES) {
            *s = model.param(i).prior_sigma;
        }
        Self::new(model, &[0.0; CAP][..n], &sigma[..n])
    }

    /// Restores a full filter state (checkpoint resume). `p` is row-major n×n.
    pub fn restore(
        &mut self,
        x: &[f64],
        p: &[f64],
        t_s: f64,
        steps: u32,
        temp_ref_c: f64,
    ) -> Result<(), FilterError> {
        let n = self.model.dim();
        if x.len() != n || p.len() != n * n {
            return Err(FilterError::Dimension {
                expected: n,
                got: x.len(),
            });
        }
        self.x[..n].copy_from_slice(x);
        for i in 0..n {
            for j in 0..n {
                self.p[(i, j)] = p[i * n + j];
            }
        }
        self.t_s = t_s;
        self.steps = steps;
        self.temp_ref_c = temp_ref_c;
        Ok(())
    }

    /// (time s, updates, temperature reference °C, temperature deviation °C, rejections).
    pub(crate) fn bookkeeping(&self) -> (f64, u32, f64, f64, u32) {
        (
            self.t_s,
            self.steps,
            self.temp_ref_c,
            self.temp_dev_c,
            self.rejected_total,
        )
    }

    #[allow(clippy::too_many_arguments)]
    pub(crate) fn set_all(
        &mut self,
        x: &[f64],
        p: &[[f64; CAP]; CAP],
        t_s: f64,
        steps: u32,
        temp_ref: f64,
        temp_dev: f64,
        rejected: u32,
    ) {
        let n = x.len();
        self.x[..n].copy_from_slice(x);
        for i in 0..n {
            for j in 0..n {
                self.p[(i, j)] = p[i][j];
            }
        }
        self.t_s = t_s;
        self.steps = steps;
        self.temp_ref_c = temp_ref;
        self.temp_dev_c = temp_dev;
        self.rejected_total = rejected;
        self.rejected_run = 0;
    }

    /// Turns innovation gating on (`Some`) or off (`None`, the default: identification from
    /// X(0) = 0 starts far from the truth and must not gate its first updates).
    pub fn set_gate(&mut self, gate: Option<Gate>) {
        self.gate = gate;
    }
    /// Measurements refused by the gate so far.
    pub fn rejected(&self) -> u32 {
        self.rejected_total
    }

    /// The model.
    pub fn model(&self) -> &Model<'m> {
        &self.model
    }
    /// Current state (length `model.dim()`): angles in rad, parameters in their units.
    pub fn state(&self) -> &[f64] {
        &self.x[..self.model.dim()]
    }
    /// Covariance entry (i, j).
    pub fn cov(&self, i: usize, j: usize) -> f64 {
        self.p[(i, j)]
    }
    /// The full covariance storage (only the leading `dim()×dim()` block is meaningful).
    pub fn covariance(&self) -> &SMatrix<f64, CAP, CAP> {
        &self.p
    }
    /// 1σ of state `i`.
    pub fn sigma(&self, i: usize) -> f64 {
        libm::sqrt(self.p[(i, i)])
    }
    /// Filter time, s.
    pub fn time_s(&self) -> f64 {
        self.t_s
    }
    /// Number of updates done.
    pub fn steps(&self) -> u32 {
        self.steps
    }
    /// Temperature at the first measurement, the reference of temperature deviations (°C; NaN if none).
    pub fn temp_ref_c(&self) -> f64 {
        self.temp_ref_c
    }

    fn temp_dev(&mut self, temp_c: f64) -> f64 {
        if !temp_c.is_finite() {
            return self.temp_dev_c;
        }
        if !self.temp_ref_c.is_finite() {
            self.temp_ref_c = temp_c;
        }
        temp_c - self.temp_ref_c
    }

    /// Propagates state and covariance to `t_s` (paper eqs. 11–12), with the temperature
    /// deviation moving linearly to `temp_dev_c`. What it overwrites goes to `saved`.
    fn predict(&mut self, t_s: f64, temp_dev_c: f64, saved: &mut Saved<CAP>) {
        let dt = t_s - self.t_s;
        if dt <= 0.0 {
            return;
        }
        let n = self.model.dim();
        let dynamic = self.model.dynamic_states();
        let nd = dynamic.len();
        saved.predicted = true;
        for (v, &d) in saved.x.iter_mut().zip(dynamic) {
            *v = self.x[d];
        }
        let mut tr = Transition::<CAP>::default();
        propagate(
            &self.model,
            &mut self.x[..n],
            self.t_s,
            dt,
            self.temp_dev_c,
            temp_dev_c,
            &mut tr,
        );
        let mut is_dyn = [false; CAP];
        for &d in dynamic {
            is_dyn[d] = true;
        }
        // Φ = [[Φ_D], [0 I]] (the dynamic rows Φ_D, identity elsewhere), so in P⁻ = Φ P Φᵀ + Q
        // only the dynamic rows/columns change: with B = Φ_D P, P⁻[D, c] = B[·, c] for the
        // other columns and P⁻[D, D] = B Φ_Dᵀ + Q_D. O(nd·n²) instead of O(n³).
        let b = &mut saved.rows;
        let data = self.p.as_slice();
        for c in 0..n {
            let col = &data[c * CAP..c * CAP + n];
            for r in 0..nd {
                b[r][c] = dot(&tr.rows[r][..n], col);
            }
        }
        let mut dd = [[0.0; MAX_DYNAMIC]; MAX_DYNAMIC];
        for r in 0..nd {
            for s in 0..=r {
                dd[r][s] = dot(&b[r][..n], &tr.rows[s][..n]) + tr.q[r][s];
                dd[s][r] = dd[r][s];
            }
        }
        for r in 0..nd {
            for (s, &e) in dynamic.iter().enumerate() {
                b[r][e] = dd[r][s];
            }
        }
        // b holds the new dynamic rows: swap them into P (keeping the old rows in b), then
        // mirror them into the columns.
        for r in 0..nd {
            let d = dynamic[r];
            for c in 0..n {
                core::mem::swap(&mut b[r][c], &mut self.p[(d, c)]);
            }
            for c in 0..n {
                if !is_dyn[c] {
                    self.p[(c, d)] = self.p[(d, c)];
                }
            }
        }
        self.t_s = t_s;
        self.temp_dev_c = temp_dev_c;
    }

    /// Undoes a prediction (and the first measurement's temperature reference). Rare: kept out
    /// of line (firmware size).
    #[cold]
    #[inline(never)]
    fn undo(&mut self, saved: &Saved<CAP>) {
        self.t_s = saved.t_s;
        self.temp_ref_c = saved.temp_ref_c;
        self.temp_dev_c = saved.temp_dev_c;
        if !saved.predicted {
            return;
        }
        let n = self.model.dim();
        for (r, &d) in self.model.dynamic_states().iter().enumerate() {
            self.x[d] = saved.x[r];
            for c in 0..n {
                self.p[(d, c)] = saved.rows[r][c];
                self.p[(c, d)] = saved.rows[r][c];
            }
        }
    }

    /// Predicts to the measurement's time and updates with it (paper eqs. 11–20, Joseph form).
    /// Returns the residual record of the update (`rejected` when the gate refused it). On error
    /// the filter is left unchanged, except [`FilterError::RejectionRun`], which keeps the
    /// prediction to that time.
    pub fn step(&mut self, m: &Measurement) -> Result<Residual, FilterError> {
        let step = self.steps;
        let ok_time = m.t_s > self.t_s || (self.steps == 0 && m.t_s >= self.t_s);
        if !ok_time || !m.t_s.is_finite() {
            return Err(FilterError::TimeNotIncreasing {
                step,
                t_s: m.t_s,
                filter_t_s: self.t_s,
            });
        }
        if m.specific_force.iter().any(|v| !v.is_finite())
            || m.variance.iter().any(|v| !(v.is_finite() && *v > 0.0))
        {
            return Err(FilterError::BadMeasurement { step });
        }
        // What the prediction changes (time, temperature, state, the dynamic rows and columns
        // of P), kept to undo it if the update is refused; the update itself writes nothing
        // before it knows it will succeed. Cheaper than a copy of the whole filter.
        let mut saved = Saved {
            predicted: false,
            t_s: self.t_s,
            temp_ref_c: self.temp_ref_c,
            temp_dev_c: self.temp_dev_c,
            x: [0.0; MAX_DYNAMIC],
            rows: [[0.0; CAP]; MAX_DYNAMIC],
        };
        let temp_dev = self.temp_dev(m.temp_c);
        self.predict(m.t_s, temp_dev, &mut saved);
        match self.update(m, temp_dev) {
            Ok(r) => {
                self.steps += 1;
                if r.rejected {
                    self.rejected_total += 1;
                    self.rejected_run += 1;
                    if let Some(g) = self.gate {
                        if self.rejected_run >= g.max_run {
                            return Err(FilterError::RejectionRun {
                                step,
                                count: self.rejected_run,
                            });
                        }
                    }
                } else {
                    self.rejected_run = 0;
                }
                Ok(r)
            }
            Err(e) => {
                self.undo(&saved);
                Err(e)
            }
        }
    }

    fn update(&mut self, m: &Measurement, temp_dev: f64) -> Result<Residual, FilterError> {
        let step = self.steps;
        let n = self.model.dim();
        let mut h = [Vector3::zeros(); CAP];
        let predicted =
            self.model
                .measurement(&self.x[..n], m.t_s, temp_dev, m.time_var_s2, &mut h);
        let nu = Vector3::from(m.specific_force) - predicted;
        let mut cols = [0usize; CAP];
        let mut nm = 0;
        for j in 0..n {
            if self.model.is_measured(j) {
                cols[nm] = j;
                nm += 1;
            }
        }
        let cols = &cols[..nm];
        // P Hᵀ (n×3), using only the measured columns of H.
        let mut pht = [Vector3::zeros(); CAP];
        {
            let data = self.p.as_slice();
            for &j in cols {
                let hj = h[j];
                for (acc, &pij) in pht[..n].iter_mut().zip(&data[j * CAP..j * CAP + n]) {
                    *acc += hj * pij;
                }
            }
        }
        let r = Vector3::from(m.variance);
        let mut s = Matrix3::from_diagonal(&r);
        for &j in cols {
            s += h[j] * pht[j].transpose();
        }
        s = (s + s.transpose()) * 0.5;
        let chol = s
            .cholesky()
            .ok_or(FilterError::SingularInnovation { step })?;
        let s_inv = chol.inverse();
        let whitened = chol
            .l()
            .solve_lower_triangular(&nu)
            .ok_or(FilterError::SingularInnovation { step })?;
        let nis = nu.dot(&(s_inv * nu));
        let residual = Residual {
            step,
            t_s: m.t_s,
            measured: m.specific_force,
            predicted: predicted.into(),
            innovation: nu.into(),
            s: s.transpose().into(),
            whitened: whitened.into(),
            nis,
            rejected: false,
        };
        if let Some(g) = self.gate {
            if nis.is_nan() || nis > g.nis_max {
                // Keep the prediction (time and covariance move on), skip the correction.
                return Ok(Residual {
                    rejected: true,
                    ..residual
                });
            }
        }
        let mut k = [Vector3::zeros(); CAP];
        for i in 0..n {
            k[i] = s_inv * pht[i];
        }
        // Joseph form P⁺ = (I−KH) P (I−KH)ᵀ + K R Kᵀ, multiplied out:
        //   P⁺ = P − K (HP) − (PHᵀ) Kᵀ + K S Kᵀ   (S = HPHᵀ + R),
        // which is the same function of K (valid for any gain, not only the optimal one) and is
        // symmetric term by term: we evaluate the upper triangle and mirror it. Only the
        // measured columns of H entered PHᵀ and S above; K and P⁺ are dense.
        let mut sk = [Vector3::zeros(); CAP];
        for c in 0..n {
            sk[c] = s * k[c];
        }
        // The diagonal and the state first: a refused update (unhealthy) writes nothing, and the
        // caller undoes the prediction.
        let mut diag = [0.0; CAP];
        let mut x_new = [0.0; CAP];
        for i in 0..n {
            let d = self.p[(i, i)] - k[i].dot(&pht[i]) - pht[i].dot(&k[i]) + k[i].dot(&sk[i]);
            let x = self.x[i] + k[i].dot(&nu);
            if !(d.is_finite() && d > 0.0 && x.is_finite()) {
                return Err(FilterError::Unhealthy { step, index: i });
            }
            diag[i] = d;
            x_new[i] = x;
        }
        let data = self.p.as_mut_slice();
        for c in 0..n {
            let (kc, phc, skc) = (k[c], pht[c], sk[c]);
            for i in 0..c {
                let v = data[c * CAP + i] - k[i].dot(&phc) - pht[i].dot(&kc) + k[i].dot(&skc);
                data[c * CAP + i] = v;
                data[i * CAP + c] = v;
            }
            data[c * CAP + c] = diag[c];
        }
        self.x[..n].copy_from_slice(&x_new[..n]);
        Ok(residual)
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// What a prediction overwrote, to undo a step whose update is refused: time, temperature,
/// the dynamic states and the dynamic rows of P (P is symmetric, so its columns follow).
struct Saved<const CAP: usize> {
    predicted: bool,
    t_s: f64,
    temp_ref_c: f64,
    temp_dev_c: f64,
    x: [f64; MAX_DYNAMIC],
    /// The prediction's scratch B = Φ_D P, then the rows of P it replaced.
    rows: [[f64; CAP]; MAX_DYNAMIC],
}
