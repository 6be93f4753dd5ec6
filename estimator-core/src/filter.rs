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
    /// NIS threshold (a χ²(3) upper quantile: 25.90 leaves a 1e-5 tail, 27.88 a 3.85e-6 tail).
    pub nis_max: f64,
    /// Consecutive rejections that raise [`FilterError::RejectionRun`].
    pub max_run: u32,
}

impl Gate {
    /// NIS above 27.88 refused (the χ²(3) upper 3.85e-6 tail; the 1e-5 quantile is 25.90),
    /// with a fault after 10 consecutive rejections.
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
        sampling::sqrt(self.p[(i, i)])
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
    #[inline(always)] // into both builds of `step`
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
        // Φ = [[Φ_D], [0 I]] (the dynamic rows Φ_D, identity elsewhere), so in P⁻ = Φ P Φᵀ + Q
        // only the dynamic rows/columns change: with B = Φ_D P, P⁻[D, c] = B[·, c] for the
        // other columns and P⁻[D, D] = B Φ_Dᵀ + Q_D. O(nd·n²) instead of O(n³).
        // B = Φ_D P three rows at a time, P's row k read along its stored column k (P is
        // symmetric; rows from nd on are zero in `tr`: their sums are unused).
        const _: () = assert!(MAX_DYNAMIC.is_multiple_of(3));
        let b = &mut saved.rows;
        let data = self.p.as_slice();
        for r0 in (0..nd).step_by(3) {
            if let [b0, b1, b2, ..] = &mut b[r0..] {
                let f = [
                    &tr.rows[r0][..n],
                    &tr.rows[r0 + 1][..n],
                    &tr.rows[r0 + 2][..n],
                ];
                three_rows_times(f, data, CAP, [&mut b0[..n], &mut b1[..n], &mut b2[..n]]);
            }
        }
        let mut dd = block_row_products(b, &tr.rows, nd, n);
        for r in 0..nd {
            for s in 0..=r {
                dd[r][s] += tr.q[r][s];
                dd[s][r] = dd[r][s];
            }
        }
        for r in 0..nd {
            for (s, &e) in dynamic.iter().enumerate() {
                b[r][e] = dd[r][s];
            }
        }
        // b holds the new dynamic rows: swap them into P (keeping the old rows in b), then
        // mirror them into the columns (where two dynamic rows cross, both hold dd's entry).
        for r in 0..nd {
            let d = dynamic[r];
            for c in 0..n {
                core::mem::swap(&mut b[r][c], &mut self.p[(d, c)]);
            }
        }
        for &d in dynamic {
            for c in 0..n {
                self.p[(c, d)] = self.p[(d, c)];
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
        #[cfg(target_arch = "x86_64")]
        if crate::cpu::has_avx2() {
            // SAFETY: `step_avx2` needs AVX2, which the CPU was just found to have.
            return unsafe { self.step_avx2(m) };
        }
        self.step_body(m)
    }

    /// [`Ekf::step`] compiled for AVX2 (x86-64 CPUs since 2013-2015; [`crate::cpu`]): the
    /// same bits (tested), the paper step 12 % faster on the host.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn step_avx2(&mut self, m: &Measurement) -> Result<Residual, FilterError> {
        self.step_body(m)
    }

    /// The step itself; inlined into both builds of [`Ekf::step`].
    #[inline(always)]
    fn step_body(&mut self, m: &Measurement) -> Result<Residual, FilterError> {
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
            || m.variance.iter().any(|v| !(*v > 0.0 && *v < f64::INFINITY))
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

    /// The measurement update after the prediction: the residual (with `rejected` set when the
    /// gate refuses it: then the state and P stay predicted), or an error writing nothing.
    #[inline(always)] // into both builds of `step`
    fn update(&mut self, m: &Measurement, temp_dev: f64) -> Result<Residual, FilterError> {
        let step = self.steps;
        let n = self.model.dim();
        let mut h = [Vector3::zeros(); CAP];
        let predicted =
            self.model
                .measurement(&self.x[..n], m.t_s, temp_dev, m.time_var_s2, &mut h);
        let nu = Vector3::from(m.specific_force) - predicted;
        // The n×3 factors of the update are kept as three columns each (`pht[a][i]` =
        // (P Hᵀ)[i][a]), contiguous over the state index: the loops over i below are then
        // plain vector operations.
        // P Hᵀ, using only the measured columns of H.
        let mut pht = [[0.0; CAP]; 3];
        let data = self.p.as_slice();
        let mut measured = self.model.measured_mask();
        while measured != 0 {
            let j = measured.trailing_zeros() as usize;
            measured &= measured - 1;
            let hj = h[j];
            let col = &data[j * CAP..j * CAP + n];
            let [p0, p1, p2] = &mut pht;
            let (p0, p1, p2) = (&mut p0[..n], &mut p1[..n], &mut p2[..n]);
            for i in 0..n {
                let pij = col[i];
                p0[i] += hj.x * pij;
                p1[i] += hj.y * pij;
                p2[i] += hj.z * pij;
            }
        }
        let s = self.innovation_covariance(&h, &pht, Vector3::from(m.variance));
        // S = L Lᵀ in closed form (3×3), S⁻¹ = L⁻ᵀ L⁻¹ and the whitened innovation L⁻¹ ν.
        let l = cholesky3(&s).ok_or(FilterError::SingularInnovation { step })?;
        let l_inv = lower_inverse3(&l);
        let s_inv = l_inv.transpose() * l_inv;
        let whitened = l_inv * nu;
        let nis = whitened.norm_squared();
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
        let mut k = [[0.0; CAP]; 3];
        let mut mm = [[0.0; CAP]; 3];
        gain(n, &pht, &s, &s_inv, &mut k, &mut mm);
        // P⁺ in Joseph form (see `joseph_update`). The diagonal and the state first: a refused
        // update (unhealthy) writes nothing, and the caller undoes the prediction.
        let mut diag = [0.0; CAP];
        let mut x_new = [0.0; CAP];
        for i in 0..n {
            let ki = [k[0][i], k[1][i], k[2][i]];
            let d = joseph(
                self.p[(i, i)],
                ki,
                [mm[0][i], mm[1][i], mm[2][i]],
                [pht[0][i], pht[1][i], pht[2][i]],
                ki,
            );
            diag[i] = d;
            x_new[i] = self.x[i] + (ki[0] * nu.x + ki[1] * nu.y + ki[2] * nu.z);
        }
        // Variances finite and positive, states finite: one branch-free pass, the index only
        // when one fails (comparisons: cheaper than `is_finite` on the target).
        let healthy = |i: usize| diag[i] > 0.0 && diag[i] * 0.0 == 0.0 && x_new[i] * 0.0 == 0.0;
        if !(0..n).fold(true, |ok, i| ok & healthy(i)) {
            let index = (0..n).find(|&i| !healthy(i)).unwrap_or(0);
            return Err(FilterError::Unhealthy { step, index });
        }
        joseph_update(self.p.as_mut_slice(), n, &pht, &k, &mm, &diag);
        self.x[..n].copy_from_slice(&x_new[..n]);
        Ok(residual)
    }

    /// S = H P Hᵀ + R (R diagonal, `r`), symmetrised; H's measured columns only.
    #[inline(always)]
    fn innovation_covariance(
        &self,
        h: &[Vector3<f64>; CAP],
        pht: &[[f64; CAP]; 3],
        r: Vector3<f64>,
    ) -> Matrix3<f64> {
        let mut s = Matrix3::from_diagonal(&r);
        let mut measured = self.model.measured_mask();
        while measured != 0 {
            let j = measured.trailing_zeros() as usize;
            measured &= measured - 1;
            let pj = Vector3::new(pht[0][j], pht[1][j], pht[2][j]);
            s += h[j] * pj.transpose();
        }
        (s + s.transpose()) * 0.5
    }
}

/// The gain K = P Hᵀ S⁻¹ and M = K S − P Hᵀ (the Joseph form's second factor, see
/// [`joseph`]) over the first `n` states, columns as `pht`.
#[inline(always)]
fn gain<const CAP: usize>(
    n: usize,
    pht: &[[f64; CAP]; 3],
    s: &Matrix3<f64>,
    s_inv: &Matrix3<f64>,
    k: &mut [[f64; CAP]; 3],
    mm: &mut [[f64; CAP]; 3],
) {
    let (p0, p1, p2) = (&pht[0][..n], &pht[1][..n], &pht[2][..n]);
    let [k0, k1, k2] = k;
    let (k0, k1, k2) = (&mut k0[..n], &mut k1[..n], &mut k2[..n]);
    let [m0, m1, m2] = mm;
    let (m0, m1, m2) = (&mut m0[..n], &mut m1[..n], &mut m2[..n]);
    for i in 0..n {
        let p = Vector3::new(p0[i], p1[i], p2[i]);
        let ki = s_inv * p;
        let mi = s * ki - p;
        (k0[i], k1[i], k2[i]) = (ki.x, ki.y, ki.z);
        (m0[i], m1[i], m2[i]) = (mi.x, mi.y, mi.z);
    }
}

/// P⁺ in place over P (`data`, column-major, `CAP` rows) given its diagonal `diag`: the
/// Joseph form's entries above the diagonal ([`joseph`]), mirrored below. Multiplied out,
///   P⁺ = (I−KH) P (I−KH)ᵀ + K R Kᵀ = P − K (HP) − (PHᵀ) Kᵀ + K S Kᵀ   (S = HPHᵀ + R)
///      = P − K (PHᵀ)ᵀ + M Kᵀ                                          (M = K S − PHᵀ),
/// the same function of K (valid for any gain, not only the optimal one), 6 products per
/// entry. Only the measured columns of H entered PHᵀ and S; K and P⁺ are dense.
#[inline(always)]
fn joseph_update<const CAP: usize>(
    data: &mut [f64],
    n: usize,
    pht: &[[f64; CAP]; 3],
    k: &[[f64; CAP]; 3],
    mm: &[[f64; CAP]; 3],
    diag: &[f64; CAP],
) {
    for c in 0..n {
        let kc = [k[0][c], k[1][c], k[2][c]];
        let phc = [pht[0][c], pht[1][c], pht[2][c]];
        let col = &mut data[c * CAP..c * CAP + c];
        let (k0, k1, k2) = (&k[0][..c], &k[1][..c], &k[2][..c]);
        let (m0, m1, m2) = (&mm[0][..c], &mm[1][..c], &mm[2][..c]);
        for i in 0..c {
            col[i] = joseph(
                col[i],
                [k0[i], k1[i], k2[i]],
                [m0[i], m1[i], m2[i]],
                phc,
                kc,
            );
        }
    }
    for c in 0..n {
        for i in 0..c {
            data[i * CAP + c] = data[c * CAP + i];
        }
        data[c * CAP + c] = diag[c];
    }
}

/// One entry of the Joseph-form update `P⁺[i][c] = P[i][c] − K[i]·PHᵀ[c] + M[i]·K[c]`.
#[inline(always)]
fn joseph(p: f64, ki: [f64; 3], mi: [f64; 3], phc: [f64; 3], kc: [f64; 3]) -> f64 {
    p - (ki[0] * phc[0] + ki[1] * phc[1] + ki[2] * phc[2])
        + (mi[0] * kc[0] + mi[1] * kc[1] + mi[2] * kc[2])
}

/// Lower Cholesky factor L of a symmetric 3×3 `S = L Lᵀ`, or `None` if S is not positive
/// definite (a pivot ≤ 0 or NaN).
fn cholesky3(s: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let l00 = sqrt_positive(s[(0, 0)])?;
    let l10 = s[(1, 0)] / l00;
    let l20 = s[(2, 0)] / l00;
    let l11 = sqrt_positive(s[(1, 1)] - l10 * l10)?;
    let l21 = (s[(2, 1)] - l20 * l10) / l11;
    let l22 = sqrt_positive(s[(2, 2)] - l20 * l20 - l21 * l21)?;
    Some(Matrix3::new(l00, 0.0, 0.0, l10, l11, 0.0, l20, l21, l22))
}

/// √v for v > 0; `None` for v ≤ 0 or NaN (a Cholesky pivot).
fn sqrt_positive(v: f64) -> Option<f64> {
    if v > 0.0 {
        Some(sampling::sqrt(v))
    } else {
        None
    }
}

/// Inverse of a lower-triangular 3×3 with a non-zero diagonal (lower-triangular too).
fn lower_inverse3(l: &Matrix3<f64>) -> Matrix3<f64> {
    let i00 = 1.0 / l[(0, 0)];
    let i11 = 1.0 / l[(1, 1)];
    let i22 = 1.0 / l[(2, 2)];
    let i10 = -l[(1, 0)] * i00 * i11;
    let i21 = -l[(2, 1)] * i11 * i22;
    let i20 = -(l[(2, 0)] * i00 + l[(2, 1)] * i10) * i22;
    Matrix3::new(i00, 0.0, 0.0, i10, i11, 0.0, i20, i21, i22)
}

/// Three rows of B = F·P for a symmetric P: `out[r][c] = Σ_k f[r][k]·P[k][c]` over the first
/// `n = out[r].len()` columns and `k < f[r].len()`, P's row k starting at `p[k * stride]`.
/// `WIDE` columns at a time (then two, then one), their sums in registers, each over k in
/// order: the prediction's Φ_D·P here and in the host's smoother (the same bits in both). Inlined: out of line, its
/// stride and widths are no longer constants of the filter's step (5 % slower on the host).
#[inline(always)]
pub fn three_rows_times(f: [&[f64]; 3], p: &[f64], stride: usize, out: [&mut [f64]; 3]) {
    let (n, kn) = (out[0].len(), f[0].len());
    // All three of a length the compiler knows (no bounds check in the loops).
    let [f0, f1, f2] = f.map(|r| &r[..kn]);
    let [o0, o1, o2] = out.map(|r| &mut r[..n]);
    let mut c = 0;
    while c + WIDE <= n {
        let a = column_block::<WIDE>([f0, f1, f2], p, stride, c);
        o0[c..c + WIDE].copy_from_slice(&a[0]);
        o1[c..c + WIDE].copy_from_slice(&a[1]);
        o2[c..c + WIDE].copy_from_slice(&a[2]);
        c += WIDE;
    }
    while c + 2 <= n {
        let a = column_block::<2>([f0, f1, f2], p, stride, c);
        o0[c..c + 2].copy_from_slice(&a[0]);
        o1[c..c + 2].copy_from_slice(&a[1]);
        o2[c..c + 2].copy_from_slice(&a[2]);
        c += 2;
    }
    if c < n {
        let a = column_block::<1>([f0, f1, f2], p, stride, c);
        (o0[c], o1[c], o2[c]) = (a[0][0], a[1][0], a[2][0]);
    }
}

/// Columns of [`three_rows_times`] per block where the registers allow: 16 double registers on
/// the Cortex-M7 (2 columns: 6 sums, 3 factors, 2 entries of P), 16 two-lane ones on x86-64.
const WIDE: usize = if cfg!(target_arch = "arm") { 2 } else { 4 };

/// `W` columns from `c` of three rows of F·P: the 3·W sums in registers, each over k in order.
#[inline(always)]
fn column_block<const W: usize>(
    f: [&[f64]; 3],
    p: &[f64],
    stride: usize,
    c: usize,
) -> [[f64; W]; 3] {
    let kn = f[0].len();
    let [f0, f1, f2] = f.map(|r| &r[..kn]);
    let mut a = [[0.0; W]; 3];
    for k in 0..kn {
        let p = &p[k * stride + c..k * stride + c + W];
        for j in 0..W {
            a[0][j] += f0[k] * p[j];
            a[1][j] += f1[k] * p[j];
            a[2][j] += f2[k] * p[j];
        }
    }
    a
}

/// `out[r][s] = Σ_c b[r][c]·f[s][c]` over the first `n` columns, for `s ≤ r < nd` (the lower
/// triangle; the rest of `out` is zero or unused): the prediction's B·Φ_Dᵀ. By 3×3 blocks, the
/// nine sums in registers over c in order, so each entry is the plain dot product to the bit;
/// one dot at a time is a chain of dependent additions (four times slower on the host).
#[inline(always)] // into both builds of `Ekf::step`
fn block_row_products<const CAP: usize>(
    b: &[[f64; CAP]; MAX_DYNAMIC],
    f: &[[f64; CAP]; MAX_DYNAMIC],
    nd: usize,
    n: usize,
) -> [[f64; MAX_DYNAMIC]; MAX_DYNAMIC] {
    let mut out = [[0.0; MAX_DYNAMIC]; MAX_DYNAMIC];
    for r0 in (0..nd).step_by(3) {
        for s0 in (0..=r0).step_by(3) {
            let mut a = [[0.0; 3]; 3];
            let (b0, b1, b2) = (&b[r0][..n], &b[r0 + 1][..n], &b[r0 + 2][..n]);
            let (f0, f1, f2) = (&f[s0][..n], &f[s0 + 1][..n], &f[s0 + 2][..n]);
            for c in 0..n {
                let (x, y, z) = (f0[c], f1[c], f2[c]);
                a[0][0] += b0[c] * x;
                a[0][1] += b0[c] * y;
                a[0][2] += b0[c] * z;
                a[1][0] += b1[c] * x;
                a[1][1] += b1[c] * y;
                a[1][2] += b1[c] * z;
                a[2][0] += b2[c] * x;
                a[2][1] += b2[c] * y;
                a[2][2] += b2[c] * z;
            }
            for (i, row) in a.iter().enumerate() {
                out[r0 + i][s0..s0 + 3].copy_from_slice(row);
            }
        }
    }
    out
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The kernel's sums are the plain ones, in the same order (so the same bits), for odd and
    /// even widths (every mix of its wide, two- and one-column blocks), fewer terms than
    /// columns, and rows of P padded to a longer stride.
    #[test]
    fn three_rows_times_is_the_plain_product() {
        let stride = 9;
        let v = |i: usize, j: usize| ((i * 31 + j * 17) % 23) as f64 * 0.37 - 4.0;
        let mut p = [0.0; 9 * 9];
        for i in 0..9 {
            for j in 0..9 {
                p[i * stride + j] = v(i.min(j), i.max(j)); // symmetric
            }
        }
        for (kn, n) in [(9, 9), (8, 8), (7, 9), (9, 7), (9, 6), (9, 1), (1, 2)] {
            let f: [[f64; 9]; 3] = core::array::from_fn(|r| core::array::from_fn(|k| v(r + 5, k)));
            let mut out = [[f64::NAN; 9]; 3];
            let [o0, o1, o2] = &mut out;
            three_rows_times(
                [&f[0][..kn], &f[1][..kn], &f[2][..kn]],
                &p,
                stride,
                [&mut o0[..n], &mut o1[..n], &mut o2[..n]],
            );
            for r in 0..3 {
                for c in 0..n {
                    let plain = (0..kn).fold(0.0f64, |acc, k| acc + f[r][k] * p[k * stride + c]);
                    assert_eq!(
                        out[r][c].to_bits(),
                        plain.to_bits(),
                        "row {r}, column {c}, {kn}x{n}"
                    );
                }
                assert!(
                    out[r][n..].iter().all(|x| x.is_nan()),
                    "wrote past column {n}"
                );
            }
        }
    }

    /// B·Φ_Dᵀ by blocks is the plain dot product of each pair of rows, to the bit, for one and
    /// two blocks of rows (the angles alone; with Gauss–Markov states) and odd widths.
    #[test]
    fn block_row_products_are_the_plain_dots() {
        let v = |i: usize, j: usize| ((i * 29 + j * 13) % 19) as f64 * 0.41 - 3.0;
        let b: [[f64; 11]; MAX_DYNAMIC] =
            core::array::from_fn(|r| core::array::from_fn(|c| v(r, c)));
        let f: [[f64; 11]; MAX_DYNAMIC] =
            core::array::from_fn(|r| core::array::from_fn(|c| v(c + 7, r)));
        for (nd, n) in [(3, 11), (3, 4), (5, 11), (6, 9)] {
            let out = block_row_products(&b, &f, nd, n);
            for r in 0..nd {
                for s in 0..=r {
                    let plain = (0..n).fold(0.0f64, |acc, c| acc + b[r][c] * f[s][c]);
                    assert_eq!(
                        out[r][s].to_bits(),
                        plain.to_bits(),
                        "({r}, {s}), nd {nd}, n {n}"
                    );
                }
            }
        }
    }

    /// An update that would leave a variance that is not positive is refused: the error names
    /// the state, and the filter is as it was before the step (the prediction undone). The
    /// covariance is restored with P[7][7] = −1e-6 (a state the measurement does not see, so
    /// nothing else in the step changes it).
    #[test]
    fn an_unhealthy_update_names_the_state_and_changes_nothing() {
        use crate::frames::Site;
        use crate::model::Propagation;
        let model = Model::new(
            Site::new(39.1, None),
            &crate::PAPER_EFFECTS,
            0.0,
            Propagation::default(),
        )
        .unwrap();
        let mut ekf = Ekf::<15>::with_default_prior(model).unwrap();
        let mut p = [0.0; 15 * 15];
        for i in 0..15 {
            p[i * 15 + i] = ekf.cov(i, i);
        }
        p[7 * 15 + 7] = -1e-6;
        ekf.restore(&[0.0; 15], &p, 0.0, 0, f64::NAN).unwrap();
        let before = ekf.clone();
        let g = model.site().gravity_mps2;
        let m = Measurement {
            t_s: 60.0,
            specific_force: [0.0, 0.0, g],
            temp_c: f64::NAN,
            count: 60,
            variance: [1e-8; 3],
            time_var_s2: 0.0,
        };
        assert_eq!(
            ekf.step(&m).unwrap_err(),
            FilterError::Unhealthy { step: 0, index: 7 }
        );
        assert_eq!(ekf.time_s(), before.time_s());
        assert_eq!(ekf.state(), before.state());
        for i in 0..15 {
            for j in 0..15 {
                assert_eq!(
                    ekf.cov(i, j).to_bits(),
                    before.cov(i, j).to_bits(),
                    "P[{i}][{j}]"
                );
            }
        }
    }

    /// The AVX2 build of the step gives the bits of the portable one (state, covariance and
    /// residuals over 300 steps of 60 s), for the paper's model and for one with Gauss–Markov
    /// and accelerometer states. On a CPU without AVX2, `step` itself is compared with the
    /// portable body (the dispatch must then take it).
    #[test]
    fn both_builds_of_the_step_give_the_same_bits() {
        use crate::effects::{AccScale, DriftMarkov, Effect, PaperDrift};
        use crate::frames::Site;
        use crate::model::Propagation;
        use crate::propagate::propagate;
        static EXTENDED: [&dyn Effect; 3] = [
            &PaperDrift,
            &DriftMarkov {
                sigma_degph: 0.01,
                tau_h: 5.0,
            },
            &AccScale,
        ];
        let site = Site::new(39.1, None);
        for effects in [&crate::PAPER_EFFECTS[..], &EXTENDED[..]] {
            let model = Model::new(site, effects, 1e-12, Propagation::default()).unwrap();
            let n = model.dim();
            let mut truth = [0.0; 24];
            truth[3..15].copy_from_slice(&[
                0.1, 0.01, -0.02, 0.03, -0.05, 0.02, 0.01, -0.01, 0.08, -0.03, 0.02, 0.015,
            ]);
            let mut tr = Transition::<24>::default();
            let mut h = [Vector3::zeros(); 24];
            let mut a = Ekf::<24>::with_default_prior(model).unwrap();
            let mut b = a.clone();
            for k in 1..=300u32 {
                propagate(
                    &model,
                    &mut truth[..n],
                    f64::from(k - 1) * 60.0,
                    60.0,
                    0.0,
                    0.0,
                    &mut tr,
                );
                let t = f64::from(k) * 60.0;
                let f = model.measurement(&truth[..n], t, 0.0, 0.0, &mut h);
                let dither = 1e-4 * libm::sin(f64::from(k) * 1.7);
                let m = Measurement {
                    t_s: t,
                    specific_force: [f.x + dither, f.y - dither, f.z + 0.5 * dither],
                    temp_c: f64::NAN,
                    count: 60,
                    variance: [1e-8; 3],
                    time_var_s2: 0.0,
                };
                #[cfg(target_arch = "x86_64")]
                let ra = if crate::cpu::has_avx2() {
                    // SAFETY: the CPU has AVX2 (checked on this line).
                    unsafe { a.step_avx2(&m) }
                } else {
                    a.step(&m)
                };
                #[cfg(not(target_arch = "x86_64"))]
                let ra = a.step(&m);
                let rb = b.step_body(&m);
                assert_eq!(ra, rb, "step {k}");
                for i in 0..n {
                    assert_eq!(
                        a.state()[i].to_bits(),
                        b.state()[i].to_bits(),
                        "x[{i}], step {k}"
                    );
                    for j in 0..n {
                        assert_eq!(a.cov(i, j).to_bits(), b.cov(i, j).to_bits(), "P[{i}][{j}]");
                    }
                }
            }
        }
    }

    /// The closed-form factor reproduces S = L·Lᵀ and its inverse S⁻¹ = L⁻ᵀ·L⁻¹ to rounding
    /// (1e-12 relative on an S with entries of order 1 and a condition number ≈ 20), and refuses
    /// a matrix that is not positive definite at each of the three pivots, and NaN.
    #[test]
    fn closed_form_cholesky_factors_and_refuses() {
        let s = Matrix3::new(4.0, 1.2, -0.6, 1.2, 3.0, 0.4, -0.6, 0.4, 2.0);
        let l = cholesky3(&s).unwrap();
        assert!((l * l.transpose() - s).amax() < 1e-12 * s.amax());
        let s_inv = lower_inverse3(&l).transpose() * lower_inverse3(&l);
        assert!((s_inv * s - Matrix3::identity()).amax() < 1e-12);
        let not_pd = [
            Matrix3::new(-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(1.0, 0.0, 2.0, 0.0, 1.0, 0.0, 2.0, 0.0, 1.0),
            Matrix3::new(f64::NAN, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        ];
        for m in not_pd {
            assert!(cholesky3(&m).is_none(), "{m}");
        }
    }
}
