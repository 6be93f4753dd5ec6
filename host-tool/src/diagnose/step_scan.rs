//! A drift step's evidence at every time from one replay of the current model: the step's
//! signature through the current filter ([`super::score`], Friedland's bias signature) carried
//! *backward*, so that one pass gives what one forward pass per time gave before (117 coarse
//! and ~60 fine passes of the 18-state filter on a 60-h run: ~0.5 s a rung; this: one observed
//! pass and one backward sweep).
//!
//! A step of sizes β (prior N(0, P)) that switches on at update j₀ adds `D_j β` to the current
//! filter's innovations from j₀ on. With z = [Ψ; T] (Ψ the filtered state's sensitivity to β,
//! T = I: the sizes are constant) the current filter carries it as
//!
//! ```text
//! z_j = F_j z_{j−1},   F_j = [(I − K_j H_j)[Φ_j  Γ_j]; 0  I],   z_{j₀−1} = E = [0; I]
//! D̃_j = C_j z_{j−1},   C_j = L_j⁻¹ (H_j [Φ_j  Γ_j] + [0  H_β,j])
//! ```
//!
//! so the score `s(j₀) = Σ_{j≥j₀} D̃_jᵀ ν̃_j` and the information `I(j₀) = Σ_{j≥j₀} D̃_jᵀ D̃_j`
//! of every j₀ come from the adjoint recursions `r_j = C_jᵀ ν̃_j + F_jᵀ r_{j+1}`,
//! `Q_j = C_jᵀ C_j + F_jᵀ Q_{j+1} F_j` as `Eᵀ r_{j₀}` and `Eᵀ Q_{j₀} E`. The model is linear in β
//! about the fit, so the filter extended by β has, exactly (the linearised pass of
//! [`super::drift_step::with_extra`]):
//!
//! ```text
//! −2 ln p(y) = −2 ln p₀(y) − sᵀ Σ s + ln det(I + P I),   Σ = (P⁻¹ + I)⁻¹
//! x̂_N = x̂₀,N + Ψ_N Σ s,   P_N = P₀,N + Ψ_N Σ Ψ_Nᵀ,   Ψ_N(j₀) = [I 0] F_N ⋯ F_{j₀} E
//! ```
//!
//! (the last from a third backward product). A unit test checks all three against the extended
//! filter's own pass.
//!
//! Memory: the replay keeps ~1.5 kB an update (Φ's dynamic rows, Γ, H, K, L⁻¹, ν̃); a record
//! beyond [`MAX_BYTES`] is profiled by one forward pass per time instead.

use estimator_core::effects::Effect;
use estimator_core::model::ANGLES;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::drift_step::DriftStep;
use super::score::{candidate_jacobians, Scratch};
use crate::identify::smoother::{linearised_pass_observed, StepView};
use crate::identify::{
    build_model, neg2_log_evidence, start_prior, Config, Identification, Prepared,
};

/// The replay's memory beyond which the scan is not used, bytes.
pub(crate) const MAX_BYTES: usize = 64 << 20;

/// One update of the current filter, as the backward sweep needs it.
struct Update {
    /// Time of the previous node, s: the step is on over this update when it is at or after t₀.
    t_prev_s: f64,
    /// Φ's dynamic rows (nd × n, row-major); Φ is the identity elsewhere.
    phi_rows: Vec<f64>,
    /// Γ (n × q) with the step on.
    gamma: DMatrix<f64>,
    /// H_β (3 × q).
    h_beta: DMatrix<f64>,
    h: DMatrix<f64>,
    k: DMatrix<f64>,
    l_inv: Matrix3<f64>,
    nu_w: Vector3<f64>,
}

/// The model with a step switching on at one update: its −2 ln p(y) and the paper's drift
/// coefficients under it (name, value, 1σ), as [`super::drift_step::Extra`].
pub(crate) struct AtUpdate {
    /// Time of the previous node, s (the step's t₀ for this update).
    pub t_prev_s: f64,
    pub extra: super::drift_step::Extra,
}

/// The drift step's evidence and coefficients for a step switching on at every update, in update
/// order (see the module docs); `None` when the replay would exceed [`MAX_BYTES`] or fails.
pub(crate) fn every_update(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
) -> Option<Vec<AtUpdate>> {
    let model = build_model(prep.site, effects, cfg).ok()?;
    let always = DriftStep {
        t0_s: f64::NEG_INFINITY,
    };
    let mut list: Vec<&dyn Effect> = effects.to_vec();
    list.push(&always);
    let extended = build_model(prep.site, &list, cfg).ok()?;
    let (n, q) = (model.dim(), extended.dim() - model.dim());
    let dynamic = model.dynamic_states().to_vec();
    let per_update = 8 * (dynamic.len() * n + n * q + 3 * q + 6 * n + 9 + 3 + 1);
    if per_update * prep.measurements.len() > MAX_BYTES || id.trajectory.len() < 2 {
        return None;
    }
    let (x0, p0) = start_prior(&model, prep, &prep.start_sigma());
    let mut updates = Vec::with_capacity(prep.measurements.len());
    let mut scratch = Scratch::default();
    let pass = linearised_pass_observed(
        &model,
        &prep.measurements,
        &id.trajectory,
        &x0,
        &p0,
        false,
        |v: &StepView<'_>| {
            let jac = candidate_jacobians(&extended, v, n, &mut scratch);
            let l_inv = v.chol_l.try_inverse().unwrap_or_else(Matrix3::identity);
            updates.push(Update {
                t_prev_s: v.t_prev_s,
                phi_rows: dynamic
                    .iter()
                    .flat_map(|&d| (0..n).map(move |c| (d, c)))
                    .map(|(d, c)| v.phi[(d, c)])
                    .collect(),
                gamma: jac.gamma,
                h_beta: jac.h_beta,
                h: v.h.clone(),
                k: v.k.clone(),
                l_inv,
                nu_w: l_inv * v.nu,
            });
        },
    )
    .ok()?;
    let base = neg2_log_evidence(&pass.innovations);
    let last = pass.states.last()?;
    let prior: Vec<f64> = (n..n + q)
        .map(|i| extended.param(i).prior_sigma.powi(2))
        .collect();
    let drift_rows: Vec<usize> = (0..12.min(id.params.len())).map(|k| ANGLES + k).collect();
    let sweep = backward(&updates, &dynamic, n, q, &drift_rows);
    let on = Final {
        base,
        last,
        cov: &pass.final_cov,
        id,
        rows: &drift_rows,
    };
    Some(
        updates
            .iter()
            .zip(sweep)
            .map(|(u, (s, info, psi))| AtUpdate {
                t_prev_s: u.t_prev_s,
                extra: on.with(&s, &info, &prior, &psi),
            })
            .collect(),
    )
}

/// The end of the current filter's pass an extra's signature is read against: its −2 ln p(y)
/// `base`, final state `last` and covariance `cov`, the fit `id` (the coefficients' names) and the
/// drift coefficients' rows `rows`.
pub(crate) struct Final<'a> {
    pub base: f64,
    pub last: &'a DVector<f64>,
    pub cov: &'a DMatrix<f64>,
    pub id: &'a Identification,
    pub rows: &'a [usize],
}

impl Final<'_> {
    /// The model plus an extra of prior variances `prior` whose signature has score `s`,
    /// information `info` and final sensitivity `psi` (Ψ_N's drift rows): −2 ln p(y) by
    /// [`marginal`], the coefficients moved by Ψ_N β̂, their variance grown by Ψ_N Σ Ψ_Nᵀ.
    pub(crate) fn with(
        &self,
        s: &DVector<f64>,
        info: &DMatrix<f64>,
        prior: &[f64],
        psi: &DMatrix<f64>,
    ) -> super::drift_step::Extra {
        let (gain, beta, sigma) = marginal(s, info, prior);
        let moved = psi * &beta;
        let spread = psi * &sigma * psi.transpose();
        super::drift_step::Extra {
            neg2_log_evidence: self.base - gain,
            drift: self
                .rows
                .iter()
                .enumerate()
                .map(|(k, &i)| {
                    let var = self.cov[(i, i)] + spread[(k, k)];
                    let value = self.last[i] + moved[k];
                    (self.id.params[k].name, value, var.max(0.0).sqrt())
                })
                .collect(),
        }
    }
}

/// The backward sweep: for every update j₀ (in order), the score s(j₀), the information I(j₀)
/// and the rows `rows` of Ψ_N(j₀) (see the module docs).
fn backward(
    updates: &[Update],
    dynamic: &[usize],
    n: usize,
    q: usize,
    rows: &[usize],
) -> Vec<(DVector<f64>, DMatrix<f64>, DMatrix<f64>)> {
    let m = n + q;
    let mut r = DVector::<f64>::zeros(m);
    let mut big_q = DMatrix::<f64>::zeros(m, m);
    let mut g = DMatrix::<f64>::from_fn(rows.len(), m, |a, b| f64::from(rows[a] == b));
    let mut p = DMatrix::<f64>::zeros(n, m);
    let mut f = DMatrix::<f64>::identity(m, m);
    let mut out = Vec::with_capacity(updates.len());
    for u in updates.iter().rev() {
        // P = [Φ Γ] (n × m): Φ the identity outside its dynamic rows.
        p.fill(0.0);
        for i in 0..n {
            p[(i, i)] = 1.0;
        }
        for (row, &d) in dynamic.iter().enumerate() {
            for c in 0..n {
                p[(d, c)] = u.phi_rows[row * n + c];
            }
        }
        p.view_mut((0, n), (n, q)).copy_from(&u.gamma);
        // D = H [Φ Γ] z + [0 H_β] z; C = L⁻¹ D's map; F's top = [Φ Γ] − K D's map (Ψ = Ψ⁻ − K D).
        let mut hp = &u.h * &p;
        let mut beta_cols = hp.view_mut((0, n), (3, q));
        beta_cols += &u.h_beta;
        let c = DMatrix::from_fn(3, 3, |a, b| u.l_inv[(a, b)]) * &hp;
        let top = &p - &u.k * &hp;
        f.view_mut((0, 0), (n, m)).copy_from(&top);
        r = c.transpose() * DVector::from_row_slice(u.nu_w.as_slice()) + f.transpose() * &r;
        big_q = c.transpose() * &c + f.transpose() * &big_q * &f;
        g = &g * &f;
        out.push((
            r.rows(n, q).into_owned(),
            big_q.view((n, n), (q, q)).into_owned(),
            g.columns(n, q).into_owned(),
        ));
    }
    out.reverse();
    out
}

/// The evidence gain (decrease of −2 ln p(y)) of parameters with prior variances `prior` whose
/// score is `s` and information `info` in a linear Gaussian model, their estimate and its
/// covariance: `sᵀ Σ s − ln det(I + P I)`, `Σ s`, `Σ = (P⁻¹ + I)⁻¹`.
pub(crate) fn marginal(
    s: &DVector<f64>,
    info: &DMatrix<f64>,
    prior: &[f64],
) -> (f64, DVector<f64>, DMatrix<f64>) {
    let q = s.len();
    let mut a = info.clone();
    for i in 0..q {
        a[(i, i)] += 1.0 / prior[i];
    }
    let sigma = a
        .clone()
        .cholesky()
        .map(|c| c.inverse())
        .unwrap_or_else(|| DMatrix::zeros(q, q));
    let beta = &sigma * s;
    // det(I + P I) = det(P) det(P⁻¹ + I).
    let ln_det = a.determinant().max(1e-300).ln() + prior.iter().map(|p| p.ln()).sum::<f64>();
    (s.dot(&beta) - ln_det, beta, sigma)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::drift_step::with_extra;

    /// The scan's evidence and coefficients at a few step times equal those of the filter
    /// extended by a step at that time, linearised about the same fit (its own forward pass, as
    /// the profile computed them before). The two are the same linear-Gaussian quantities by two
    /// routes (augmented state vs. signature), so they agree to rounding: 1e-6 of −2 ln p(y)'s
    /// change, 1e-6 of each coefficient's 1σ.
    #[test]
    fn the_scan_equals_the_extended_filter_at_every_time() {
        use crate::identify::identify;
        use crate::simulate::{InjectedEffect, Scenario};
        // 24 h at 60 s with a drift step at 9 h the model lacks: the fit bends, the scan's gains
        // are large (the comparison is then a relative one) and the step's Γ is exercised.
        let mut sc = Scenario::paper();
        sc.hours = 24.0;
        sc.rate_s = 60.0;
        sc.effects = vec![InjectedEffect::DriftStep {
            a_deg_h: [0.002, -0.001, 0.0015],
            t0_h: 9.0,
        }];
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let effects = [crate::catalog::paper()];
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let scan = every_update(&prep, &effects, &cfg, &id).expect("the scan runs");
        assert_eq!(scan.len(), prep.measurements.len());
        for j in [40, scan.len() / 2, scan.len() - 30] {
            let t0 = scan[j].t_prev_s;
            let direct = with_extra(&prep, &effects, &cfg, &id, &DriftStep { t0_s: t0 })
                .expect("the extended pass runs");
            let (a, b) = (&scan[j].extra, &direct);
            // −2 ln p(y) is a sum of 1440 terms of ~±50: rounding leaves ~1e-5 of its ~7e4.
            let base = neg2_log_evidence(&id.innovations);
            let tol = 1e-9 * b.neg2_log_evidence.abs() + 1e-6 * (base - b.neg2_log_evidence).abs();
            eprintln!(
                "update {j}: gain {:.4}, scan − extended {:.2e}",
                base - b.neg2_log_evidence,
                a.neg2_log_evidence - b.neg2_log_evidence
            );
            assert!(
                (a.neg2_log_evidence - b.neg2_log_evidence).abs() < tol,
                "update {j}: scan {} vs extended {}",
                a.neg2_log_evidence,
                b.neg2_log_evidence
            );
            for (x, y) in a.drift.iter().zip(&b.drift) {
                assert!(
                    (x.1 - y.1).abs() < 1e-6 * y.2,
                    "{}: {} vs {}",
                    x.0,
                    x.1,
                    y.1
                );
                assert!(
                    (x.2 - y.2).abs() < 1e-6 * y.2,
                    "{}: σ {} vs {}",
                    x.0,
                    x.2,
                    y.2
                );
            }
        }
    }
}
