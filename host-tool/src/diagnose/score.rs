//! Score (Lagrange-multiplier) tests of candidate effects from one replay of the current model.
//!
//! Under the current model H0 the filter's innovations ν_j are white with covariance S_j. If an
//! effect with parameters β (zero under H0) is present, the same filter's innovations become
//! `ν_j + D_j β`, where the *signature* D_j follows from a recursion through the H0 filter
//! (Basseville & Nikiforov; Friedland's bias signatures):
//!
//! ```text
//! Ψ⁻_j = Φ_j Ψ_{j−1} + Γ_j T_{j−1}      Γ_j = ∂x_j/∂β over the interval (true dynamics)
//! T_j  = A_j T_{j−1}                     β's own dynamics (identity for constants)
//! D_j  = H_j Ψ⁻_j + H_β,j T_j            Ψ_j = Ψ⁻_j − K_j D_j
//! ```
//! Whitening with S_j = L_j L_jᵀ, the score is `s = Σ D̃_jᵀ ν̃_j` and the information
//! `I = Σ D̃_jᵀ D̃_j`; the statistic `sᵀ I⁺ s` is χ² with rank(I) degrees of freedom under H0.
//! `I⁺ s` is the one-step estimate of β and `I⁺` its covariance. Γ, A and H_β come from the
//! core's own propagation and measurement Jacobians of the model extended by the candidate,
//! evaluated on the nominal (smoothed) trajectory with β = 0: no model code is duplicated here.
//! The constant candidates of a replay share one linearisation, of the model extended by all of
//! them ([`combinable`]): the same bits as each one's own.

use estimator_core::effects::Effect;
use estimator_core::model::{Model, MAX_EFFECTS, MAX_STATES};
use estimator_core::propagate::{propagate, Transition};
use estimator_core::Measurement;
use nalgebra::{DMatrix, DVector, SymmetricEigen, Vector3};

use crate::identify::smoother::{linearised_pass_observed, Smoothed, SmootherError, StepView};

/// The signature of one candidate and its test.
pub(crate) struct Signature {
    /// Parameters tested.
    pub q: usize,
    /// Score Σ D̃ᵀ ν̃.
    pub score: DVector<f64>,
    /// Information Σ D̃ᵀ D̃.
    pub info: DMatrix<f64>,
    /// Whitened signature, 3 rows per update (3N × q).
    pub whitened: DMatrix<f64>,
    /// Ψ at the last update (n × q): the parameters are constants, so their smoothed estimate
    /// is the last filtered one, and adding β to the model moves it by `Ψ β`.
    pub psi_final: DMatrix<f64>,
}

/// Result of a score test.
pub(crate) struct ScoreTest {
    /// Statistic sᵀ I⁺ s.
    pub statistic: f64,
    /// Rank of I (identifiable directions).
    pub dof: usize,
    /// One-step estimate I⁺ s.
    pub estimate: DVector<f64>,
    /// Its covariance I⁺.
    pub cov: DMatrix<f64>,
}

impl Signature {
    /// Pseudo-inverse test: I is scaled to unit diagonal, directions with eigenvalue below 1e-9
    /// of the largest are unidentifiable on this run and dropped from the test.
    pub(crate) fn test(&self) -> ScoreTest {
        let q = self.q;
        let scale: Vec<f64> = (0..q).map(|k| self.info[(k, k)].sqrt()).collect();
        let inv_scale: Vec<f64> = scale
            .iter()
            .map(|&s| if s > 0.0 { 1.0 / s } else { 0.0 })
            .collect();
        let is = DMatrix::from_fn(q, q, |a, b| self.info[(a, b)] * inv_scale[a] * inv_scale[b]);
        let ss = DVector::from_fn(q, |a, _| self.score[a] * inv_scale[a]);
        let eig = SymmetricEigen::new(is);
        let lmax = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
        let mut pinv = DMatrix::zeros(q, q);
        let mut dof = 0;
        for (k, &l) in eig.eigenvalues.iter().enumerate() {
            if lmax > 0.0 && l > 1e-9 * lmax {
                let u = eig.eigenvectors.column(k);
                pinv += u * u.transpose() / l;
                dof += 1;
            }
        }
        let cov = DMatrix::from_fn(q, q, |a, b| pinv[(a, b)] * inv_scale[a] * inv_scale[b]);
        let estimate = &cov * &self.score;
        let statistic = ss.dot(&(&pinv * &ss));
        ScoreTest {
            statistic,
            dof,
            estimate,
            cov,
        }
    }
}

/// One signature recursion (of a candidate effect, or of the set-up's knobs), carried along the
/// replay of the current model.
pub(crate) struct Tracker {
    /// The parameter count (columns of Ψ).
    q: usize,
    /// The rows of Ψ the prediction changes: the current model's dynamic rows (Φ) and those
    /// where Γ can be nonzero.
    rows: Vec<usize>,
    /// β's own Gauss–Markov rows (A is the identity elsewhere), counted from 0.
    own: Vec<usize>,
    /// The current model's measured states: H is zero in every other column.
    measured: Vec<usize>,
    /// Ψ: the sensitivity of the current model's filtered state to β (n × q).
    psi: DMatrix<f64>,
    /// T: the sensitivity of β's own states to their start (q × q; identity for constants).
    t: DMatrix<f64>,
    /// Σ D̃ᵀ ν̃.
    score: DVector<f64>,
    /// Σ D̃ᵀ D̃.
    info: DMatrix<f64>,
    /// The whitened signature's rows, 3 per update, q values each (when kept).
    whitened: Option<Vec<f64>>,
    /// Buffers of one step (Ψ⁻, D, D̃), reused: a replay steps every candidate at every update,
    /// and allocating them anew was a fifth of its time.
    psi_pred: DMatrix<f64>,
    d: DMatrix<f64>,
    dw: DMatrix<f64>,
}

/// The candidate's Jacobians over one step: Γ (n × q, ∂x_j/∂β over the interval), A (q × q, β's
/// own dynamics) and H_β (3 × q).
pub(crate) struct StepJacobians {
    pub gamma: DMatrix<f64>,
    pub a: DMatrix<f64>,
    pub h_beta: DMatrix<f64>,
}

/// Scratch buffers of the core's propagation and measurement Jacobians, reused at every step.
pub(crate) struct Scratch {
    pub(crate) tr: Transition<MAX_STATES>,
    pub(crate) cols: [Vector3<f64>; MAX_STATES],
    /// The extended state at a node (the nominal, the candidate's parameters zero).
    x: Vec<f64>,
}

impl Default for Scratch {
    fn default() -> Self {
        Scratch {
            tr: Transition::<MAX_STATES>::default(),
            cols: [Vector3::zeros(); MAX_STATES],
            x: Vec::with_capacity(MAX_STATES),
        }
    }
}

/// Γ, A and H_β of `extended` (the current model of `n` states followed by a candidate's) over
/// the step `v`, from the core's propagation and measurement on the nominal trajectory with
/// β = 0.
pub(crate) fn candidate_jacobians(
    extended: &Model<'_>,
    v: &StepView<'_>,
    n: usize,
    scratch: &mut Scratch,
) -> StepJacobians {
    let q = extended.dim() - n;
    let mut jac = StepJacobians {
        gamma: DMatrix::zeros(n, q),
        a: DMatrix::identity(q, q),
        h_beta: DMatrix::zeros(3, q),
    };
    candidate_jacobians_into(extended, v, n, scratch, &mut jac);
    jac
}

/// [`candidate_jacobians`] into `jac` (shaped n × q, q × q and 3 × q; made as
/// [`candidate_jacobians`] makes it, or filled last for the same `extended`: see
/// [`columns_into`]): a replay steps every candidate at every update, and five fresh buffers a
/// step were ~a tenth of a profile's replay.
pub(crate) fn candidate_jacobians_into(
    extended: &Model<'_>,
    v: &StepView<'_>,
    n: usize,
    scratch: &mut Scratch,
    jac: &mut StepJacobians,
) {
    linearise_into(extended, v, scratch);
    columns_into(extended, scratch, n, n, jac);
}

/// The core's propagation (Φ's rows in `scratch.tr`) and measurement Jacobian (`scratch.cols`)
/// of `extended` over the step `v`, on the nominal trajectory with every parameter it adds to
/// the nominal's zero.
fn linearise_into(extended: &Model<'_>, v: &StepView<'_>, scratch: &mut Scratch) {
    let dim = extended.dim();
    let (tr, x) = (&mut scratch.tr, &mut scratch.x);
    let at = |x: &mut Vec<f64>, nominal: &DVector<f64>| {
        x.clear();
        x.extend_from_slice(nominal.as_slice());
        x.resize(dim, 0.0);
    };
    at(x, v.nominal_prev);
    propagate(
        extended,
        x,
        v.t_prev_s,
        v.t_s - v.t_prev_s,
        v.temp_prev,
        v.temp,
        tr,
    );
    at(x, v.nominal);
    extended.measurement(x, v.t_s, v.temp, v.time_var_s2, &mut scratch.cols);
}

/// Γ, A and H_β of the `jac.h_beta.ncols()` states of `extended` from `off` (one candidate's
/// parameters), read off its linearisation in `scratch` ([`linearise_into`]). Only Γ's and A's
/// entries in `extended`'s dynamic rows are written, the same ones at every step: the rest keep
/// the zeros and the identity `jac` was made with (clearing them at every step was a third of
/// this function's time in a replay).
fn columns_into(
    extended: &Model<'_>,
    scratch: &Scratch,
    n: usize,
    off: usize,
    jac: &mut StepJacobians,
) {
    let q = jac.h_beta.ncols();
    for (r, &d) in extended.dynamic_states().iter().enumerate() {
        for b in 0..q {
            if d < n {
                jac.gamma[(d, b)] = scratch.tr.rows[r][off + b];
            } else if (off..off + q).contains(&d) {
                jac.a[(d - off, b)] = scratch.tr.rows[r][off + b];
            }
        }
    }
    for b in 0..q {
        jac.h_beta.set_column(b, &scratch.cols[off + b]);
    }
}

/// A model whose one linearisation gives several candidates' Jacobians: the current model's
/// effects followed by every member's ([`combinable`]), each member's columns from its offset
/// there. At β = 0 a candidate's columns
/// of Φ and H are the same products and sums in the combined model as in its own extended
/// model (the other members add exact zeros to f, to F's angle rows and to h), so its
/// Jacobians come out bit for bit as its own linearisation gives them
/// (`a_combined_linearisation_gives_each_candidates_jacobians_bit_for_bit`); one linearisation
/// instead of one per candidate was most of a replay's time beside the trackers.
struct Combined<'m> {
    model: Model<'m>,
    scratch: Scratch,
}

/// The candidates of `extended` a combined linearisation may carry, in groups that fit the
/// state and effect capacities: those that add one effect to the current model's, with no
/// Gauss–Markov state of their own (the sub-steps and Φ's dynamic rows stay the current
/// model's) and not using north (its chain adds to F's angle columns). Groups of one are left
/// to their own linearisation.
fn combinable(model: &Model<'_>, extended: &[Option<Model<'_>>]) -> Vec<Vec<usize>> {
    let base = model.effects();
    let mut groups: Vec<Vec<usize>> = vec![];
    // The open group's states and effects.
    let (mut states, mut effects) = (model.dim(), base.len());
    for (c, m) in extended.iter().enumerate() {
        let Some(m) = m else { continue };
        let own = m.effects();
        let adds_one = own.len() == base.len() + 1
            && own.iter().zip(base).all(|(a, b)| std::ptr::addr_eq(*a, *b));
        if !adds_one || m.dynamic_states() != model.dynamic_states() || own[base.len()].uses_north()
        {
            continue;
        }
        let q = m.dim() - model.dim();
        if groups.is_empty() || states + q > MAX_STATES || effects + 1 > MAX_EFFECTS {
            groups.push(vec![]);
            (states, effects) = (model.dim(), base.len());
        }
        if let Some(g) = groups.last_mut() {
            g.push(c);
        }
        (states, effects) = (states + q, effects + 1);
    }
    groups.retain(|g| g.len() > 1);
    groups
}

impl Tracker {
    /// The recursion's start for `q` parameters on the `current` model: Ψ = `psi0` (n × q, the
    /// start's sensitivity to β), Γ nonzero only in the current model's dynamic rows and
    /// `gamma_rows`, β's own dynamics in its rows `own`; `keep_whitened` keeps the whitened
    /// signature (3 rows per update) for comparing footprints.
    pub(crate) fn new(
        psi0: DMatrix<f64>,
        current: &Model<'_>,
        gamma_rows: &[usize],
        own: Vec<usize>,
        keep_whitened: Option<usize>,
    ) -> Self {
        let (psi0_rows, q) = psi0.shape();
        let mut rows: Vec<usize> = current
            .dynamic_states()
            .iter()
            .chain(gamma_rows)
            .copied()
            .collect();
        rows.sort_unstable();
        rows.dedup();
        Tracker {
            q,
            rows,
            own,
            measured: (0..current.dim())
                .filter(|&i| current.is_measured(i))
                .collect(),
            psi: psi0,
            t: DMatrix::identity(q, q),
            score: DVector::zeros(q),
            info: DMatrix::zeros(q, q),
            whitened: keep_whitened.map(|updates| Vec::with_capacity(3 * q * updates)),
            psi_pred: DMatrix::zeros(psi0_rows, q),
            d: DMatrix::zeros(3, q),
            dw: DMatrix::zeros(3, q),
        }
    }

    /// The recursion of candidate `extended` (the `current` model extended by the candidate)
    /// over `updates` measurement updates (`None`: its whitened signature is not kept).
    fn for_candidate(extended: &Model<'_>, current: &Model<'_>, updates: Option<usize>) -> Self {
        let n = current.dim();
        let ext = extended.dynamic_states();
        let gamma_rows: Vec<usize> = ext.iter().copied().filter(|&d| d < n).collect();
        let own = ext.iter().filter(|&&d| d >= n).map(|&d| d - n).collect();
        let q = extended.dim() - n;
        Tracker::new(DMatrix::zeros(n, q), current, &gamma_rows, own, updates)
    }

    /// One update of the replay: the signature D_j of this step from its Jacobians `jac`, then
    /// Ψ and the score and information with the whitened innovation `nu_w`.
    ///
    /// Written out on slices rather than with nalgebra's general products: a replay steps every
    /// candidate at every update, and on these small shapes (3 × n times n × q) the general
    /// code's dispatch and bounds checks were most of a replay's time.
    pub(crate) fn step(&mut self, v: &StepView<'_>, jac: &StepJacobians, nu_w: &Vector3<f64>) {
        self.predict_psi(v, &jac.gamma);
        self.advance_own_dynamics(&jac.a);
        self.signature(v, &jac.h_beta);
        // Ψ = Ψ⁻ − K D, column by column.
        let n = self.psi.nrows();
        let k = v.k.as_slice();
        let (k0, k1, k2) = (&k[..n], &k[n..2 * n], &k[2 * n..3 * n]);
        for b in 0..self.q {
            let db = self.d.column(b);
            let (d0, d1, d2) = (db[0], db[1], db[2]);
            let pred = &self.psi_pred.as_slice()[b * n..(b + 1) * n];
            let out = &mut self.psi.as_mut_slice()[b * n..(b + 1) * n];
            for i in 0..n {
                out[i] = pred[i] - (k0[i] * d0 + k1[i] * d1 + k2[i] * d2);
            }
        }
        self.accumulate(&v.chol_l, nu_w);
    }

    /// Whether β's own dynamics are the identity (no Gauss–Markov rows): then T stays I.
    fn constant(&self) -> bool {
        self.own.is_empty()
    }

    /// Ψ⁻ = Φ Ψ + Γ T into `psi_pred`: Φ is the identity outside the current model's dynamic
    /// rows and Γ zero outside its own rows: only those rows change.
    fn predict_psi(&mut self, v: &StepView<'_>, gamma: &DMatrix<f64>) {
        let (n, q) = self.psi.shape();
        self.psi_pred.copy_from(&self.psi);
        let constant = self.constant();
        let mut phi_row = [0.0; MAX_STATES];
        for &d in &self.rows {
            for (k, x) in phi_row[..n].iter_mut().enumerate() {
                *x = v.phi[(d, k)];
            }
            for b in 0..q {
                let col = &self.psi.as_slice()[b * n..(b + 1) * n];
                let mut acc: f64 = phi_row[..n].iter().zip(col).map(|(a, b)| a * b).sum();
                if constant {
                    acc += gamma[(d, b)];
                } else {
                    for c in 0..q {
                        acc += gamma[(d, c)] * self.t[(c, b)];
                    }
                }
                self.psi_pred[(d, b)] = acc;
            }
        }
    }

    /// D = H Ψ⁻ + H_β T into `d` (3 × q). H's columns outside the measured states are zero and
    /// are skipped: their products are ±0, which leave a sum started at +0 as it is (the same
    /// bits), and on the paper's model only the 3 angles of 15 states are measured.
    fn signature(&mut self, v: &StepView<'_>, h_beta: &DMatrix<f64>) {
        let (n, q) = self.psi.shape();
        let h = v.h.as_slice();
        for b in 0..q {
            let col = &self.psi_pred.as_slice()[b * n..(b + 1) * n];
            let mut acc = Vector3::zeros();
            for &k in &self.measured {
                acc += Vector3::new(h[3 * k], h[3 * k + 1], h[3 * k + 2]) * col[k];
            }
            if self.constant() {
                acc += h_beta.column(b);
            } else {
                acc += h_beta * self.t.column(b);
            }
            self.d.set_column(b, &acc);
        }
    }

    /// T ← A T: A is the identity outside the candidate's Gauss–Markov rows.
    fn advance_own_dynamics(&mut self, a: &DMatrix<f64>) {
        let q = self.q;
        let new_rows: Vec<(usize, Vec<f64>)> = self
            .own
            .iter()
            .map(|&r| {
                let row = (0..q)
                    .map(|b| (0..q).fold(0.0, |acc, c| acc + a[(r, c)] * self.t[(c, b)]))
                    .collect();
                (r, row)
            })
            .collect();
        for (r, row) in new_rows {
            for (b, x) in row.into_iter().enumerate() {
                self.t[(r, b)] = x;
            }
        }
    }

    /// Whitens the signature D (D̃ = L⁻¹ D column by column, L the 3×3 lower-triangular
    /// factor of S) and adds it to the score, the information (both triangles from one
    /// product each: it stays exactly symmetric) and the whitened rows.
    fn accumulate(&mut self, l: &nalgebra::Matrix3<f64>, nu_w: &Vector3<f64>) {
        let q = self.q;
        for b in 0..q {
            let c = Vector3::new(self.d[(0, b)], self.d[(1, b)], self.d[(2, b)]);
            let w = l.solve_lower_triangular(&c).unwrap_or(c);
            self.dw.set_column(b, &w);
        }
        let dw = &self.dw;
        for b in 0..q {
            let wb = dw.fixed_view::<3, 1>(0, b);
            self.score[b] += wb.dot(nu_w);
            for a in 0..=b {
                let x = dw.fixed_view::<3, 1>(0, a).dot(&wb);
                self.info[(a, b)] += x;
                if a != b {
                    self.info[(b, a)] += x;
                }
            }
        }
        if let Some(rows) = self.whitened.as_mut() {
            for i in 0..3 {
                rows.extend(dw.row(i).iter());
            }
        }
    }

    /// The signature at the end of the replay.
    pub(crate) fn into_signature(self) -> Signature {
        let rows = self.whitened.unwrap_or_default();
        let n_rows = rows.len() / self.q.max(1);
        Signature {
            q: self.q,
            score: self.score,
            info: self.info,
            whitened: DMatrix::from_row_slice(n_rows, self.q, &rows),
            psi_final: self.psi,
        }
    }
}

/// What [`signatures`] returns: the pass, each candidate's signature, the whitened innovations
/// (3 per update).
pub(crate) type Replay = (Smoothed, Vec<Option<Signature>>, Vec<f64>);

/// Replays the current model's final forward pass once and carries every candidate's signature.
/// `extended[c]` is the current model's effects followed by candidate c's (its state layout
/// extends the current one). Returns the pass and, per candidate, its signature (`None` when
/// the extended model does not fit in the state capacity), or the pass's error (naming the
/// update) when the linearised filter breaks down on these measurements.
pub(crate) fn signatures(
    model: &Model<'_>,
    extended: &[Option<Model<'_>>],
    meas: &[Measurement],
    nominal: &[DVector<f64>],
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
) -> Result<Replay, SmootherError> {
    signatures_kept(model, extended, meas, (nominal, x0, p0), true)
}

/// [`signatures`], the whitened signatures kept only when `keep_whitened` (a profile needs only
/// each candidate's score, information and final Ψ).
///
/// Called outside rayon's pool (the ladder's score tests, a misfit's catalog weighed before its
/// refits: nothing else runs then) with [`SPLIT_FROM`] candidates or more, the candidates are
/// shared between two passes, one on each core ([`two_shares`]): one pass more of CPU, and about
/// half the trackers' time off the wall (a replay of 7–9 candidates on a 60-h run: 0.10–0.12 s
/// on one core). A candidate's tracker reads only the pass and its own state, and the pass is
/// the same on either core: the same bits.
pub(crate) fn signatures_kept(
    model: &Model<'_>,
    extended: &[Option<Model<'_>>],
    meas: &[Measurement],
    around: (&[DVector<f64>], &DVector<f64>, &DMatrix<f64>),
    keep_whitened: bool,
) -> Result<Replay, SmootherError> {
    let outside_pool = rayon::current_thread_index().is_none();
    if !outside_pool || extended.iter().flatten().count() < SPLIT_FROM {
        return signatures_of(model, extended, meas, around, keep_whitened);
    }
    let shares = two_shares(model.dim(), extended);
    let of = |share: &[usize]| -> Vec<Option<Model<'_>>> {
        share.iter().map(|&c| extended[c]).collect()
    };
    let (a, b) = rayon::join(
        || signatures_of(model, &of(&shares[0]), meas, around, keep_whitened),
        || signatures_of(model, &of(&shares[1]), meas, around, keep_whitened),
    );
    let (pass, sigs_a, nu_whitened) = a?;
    let (_, sigs_b, _) = b?;
    let mut sigs: Vec<Option<Signature>> = extended.iter().map(|_| None).collect();
    for (&c, s) in shares[0]
        .iter()
        .chain(&shares[1])
        .zip(sigs_a.into_iter().chain(sigs_b))
    {
        sigs[c] = s;
    }
    Ok((pass, sigs, nu_whitened))
}

/// Candidates from which a replay outside rayon's pool is shared between two passes
/// ([`signatures_kept`]): each candidate's tracker costs at least what the pass itself does
/// (60 h at 60 s: the pass ~8 ms, a candidate ~6 ms + 1 ms per added state).
const SPLIT_FROM: usize = 3;

/// The candidates (indices into `extended`; `n`: the current model's states) in two shares of
/// about equal work, the largest first each to the lighter share. A tracker's time grows with
/// the states its candidate adds, q: ~6 + q in ms on a 60-h run (measured one by one: q = 3,
/// 6, 15, 36 took 9, 10–12, 20, 41 ms).
fn two_shares(n: usize, extended: &[Option<Model<'_>>]) -> [Vec<usize>; 2] {
    let cost = |c: usize| extended[c].as_ref().map_or(0, |m| 6 + m.dim() - n);
    let mut order: Vec<usize> = (0..extended.len()).collect();
    order.sort_by_key(|&c| std::cmp::Reverse(cost(c)));
    let mut shares = [vec![], vec![]];
    let mut load = [0, 0];
    for c in order {
        let s = usize::from(load[1] < load[0]);
        load[s] += cost(c);
        shares[s].push(c);
    }
    shares
}

/// [`signatures_kept`] on this thread: one pass, every candidate's tracker stepping with it.
fn signatures_of(
    model: &Model<'_>,
    extended: &[Option<Model<'_>>],
    meas: &[Measurement],
    (nominal, x0, p0): (&[DVector<f64>], &DVector<f64>, &DMatrix<f64>),
    keep_whitened: bool,
) -> Result<Replay, SmootherError> {
    let n = model.dim();
    let kept = keep_whitened.then_some(meas.len());
    let mut trackers: Vec<Option<(&Model<'_>, Tracker, StepJacobians)>> = extended
        .iter()
        .map(|m| {
            m.as_ref().map(|m| {
                let q = m.dim() - n;
                let jac = StepJacobians {
                    gamma: DMatrix::zeros(n, q),
                    a: DMatrix::identity(q, q),
                    h_beta: DMatrix::zeros(3, q),
                };
                (m, Tracker::for_candidate(m, model, kept), jac)
            })
        })
        .collect();
    let groups = combinable(model, extended);
    let lists: Vec<Vec<&dyn Effect>> = groups
        .iter()
        .map(|g| {
            let added = g.iter().flat_map(|&c| extended[c].as_ref()).map(|m| {
                let own = m.effects();
                own[own.len() - 1]
            });
            model.effects().iter().copied().chain(added).collect()
        })
        .collect();
    // Per candidate: its combined model and first column there (`None`: its own).
    let mut combined: Vec<Combined<'_>> = vec![];
    let mut member_of = vec![None; extended.len()];
    for (g, list) in groups.iter().zip(&lists) {
        let Ok(m) = Model::new(*model.site(), list, model.arw_rad2ps(), model.propagation()) else {
            continue;
        };
        let mut off = n;
        for &c in g {
            member_of[c] = Some((combined.len(), off));
            off += extended[c].as_ref().map_or(0, |e| e.dim() - n);
        }
        combined.push(Combined {
            model: m,
            scratch: Scratch::default(),
        });
    }
    let mut nu_whitened = Vec::with_capacity(3 * meas.len());
    // The trackers step with the pass, on its thread: the pass may hold rayon's workers (its
    // linearisation ahead), and work handed to the pool from here waited for them forever
    // (tests running side by side deadlocked).
    let mut scratch = Scratch::default();
    let pass = linearised_pass_observed(model, meas, nominal, x0, p0, false, |v: &StepView<'_>| {
        let nu_w = v.chol_l.solve_lower_triangular(&v.nu).unwrap_or(v.nu);
        nu_whitened.extend_from_slice(nu_w.as_slice());
        for c in &mut combined {
            linearise_into(&c.model, v, &mut c.scratch);
        }
        for (entry, member) in trackers.iter_mut().zip(&member_of) {
            let Some((m, tk, jac)) = entry else { continue };
            match *member {
                Some((g, off)) => {
                    columns_into(&combined[g].model, &combined[g].scratch, n, off, jac)
                }
                None => candidate_jacobians_into(m, v, n, &mut scratch, jac),
            }
            tk.step(v, jac, &nu_w);
        }
    });
    let pass = pass?;
    let sigs = trackers
        .into_iter()
        .map(|tk| tk.map(|(_, t, _)| t.into_signature()))
        .collect();
    Ok((pass, sigs, nu_whitened))
}

/// Orthonormal basis of the column space of `w` (directions with singular value above 1e-6 of
/// the largest).
fn basis(w: &DMatrix<f64>) -> DMatrix<f64> {
    let svd = w.clone().svd(true, false);
    let u = svd.u.unwrap();
    let smax = svd.singular_values.iter().cloned().fold(0.0, f64::max);
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&k| svd.singular_values[k] > 1e-6 * smax)
        .collect();
    DMatrix::from_fn(u.nrows(), keep.len(), |i, j| u[(i, keep[j])])
}

/// Orthonormal basis of a signature's footprint in the innovations: the span of its whitened
/// columns ([`canonical_correlation`] compares two).
pub(crate) fn footprint(s: &Signature) -> DMatrix<f64> {
    basis(&s.whitened)
}

/// Largest canonical correlation between two signatures' footprints ([`footprint`]): how alike
/// they are in the innovations (1 = indistinguishable on this run).
pub(crate) fn canonical_correlation(qa: &DMatrix<f64>, qb: &DMatrix<f64>) -> f64 {
    if qa.ncols() == 0 || qb.ncols() == 0 {
        return 0.0;
    }
    let m = qa.transpose() * qb;
    m.singular_values()
        .iter()
        .cloned()
        .fold(0.0, f64::max)
        .min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::drift_step::with_extra;
    use crate::diagnose::step_scan::marginal;
    use crate::identify::{build_model, identify, neg2_log_evidence, start_prior, Config};

    /// A replay shared between two passes (outside rayon's pool, as the test thread is) hands
    /// back every candidate's signature bit for bit as one pass carrying them all, in the
    /// candidates' order (a candidate that does not fit stays `None` in its place), and the
    /// same pass. Five candidates of 3–18 added states, so the shares are mixed.
    #[test]
    fn a_shared_replay_is_the_single_replay_bit_for_bit() {
        use crate::simulate::{InjectedEffect, Scenario};
        let mut sc = Scenario::paper();
        (sc.hours, sc.rate_s) = (12.0, 60.0);
        sc.effects = vec![InjectedEffect::AccBias {
            b_mps2: [1e-4, -5e-5, 8e-5],
        }];
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let paper = crate::catalog::paper();
        let current = [paper];
        let model = build_model(prep.site, &current, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let names = ["g2", "acc-bias", "drift-trend", "acc-scale", "drift-daily"];
        let lists: Vec<[&dyn estimator_core::effects::Effect; 2]> = names
            .iter()
            .map(|n| [paper, crate::catalog::builtin(n).unwrap()])
            .collect();
        let mut extended: Vec<Option<Model<'_>>> = lists
            .iter()
            .map(|l| Some(build_model(prep.site, l, &cfg).unwrap()))
            .collect();
        extended.insert(2, None);
        let (x0, p0) = start_prior(&model, &prep, &prep.start_sigma());
        let around = (&id.trajectory[..], &x0, &p0);
        assert!(rayon::current_thread_index().is_none());
        let shares = two_shares(model.dim(), &extended);
        assert!(shares.iter().all(|s| !s.is_empty()), "{shares:?}");
        let (one, one_sigs, one_nu) =
            signatures_of(&model, &extended, &prep.measurements, around, true).unwrap();
        let (two, two_sigs, two_nu) =
            signatures_kept(&model, &extended, &prep.measurements, around, true).unwrap();
        assert_eq!(one.states, two.states);
        assert_eq!(one_nu, two_nu);
        assert_eq!(one_sigs.len(), two_sigs.len());
        for (k, (a, b)) in one_sigs.iter().zip(&two_sigs).enumerate() {
            match (a, b) {
                (Some(a), Some(b)) => {
                    assert_eq!(a.q, b.q, "candidate {k}");
                    assert_eq!(a.score, b.score, "candidate {k}");
                    assert_eq!(a.info, b.info, "candidate {k}");
                    assert_eq!(a.whitened, b.whitened, "candidate {k}");
                    assert_eq!(a.psi_final, b.psi_final, "candidate {k}");
                }
                (None, None) => assert_eq!(k, 2),
                _ => panic!("candidate {k}: one replay has its signature, the other not"),
            }
        }
    }

    /// Each constant candidate's signature, carried through one replay of the current filter,
    /// gives what the filter extended by the candidate gives on its own pass linearised about
    /// the same fit (the exact linear-Gaussian identity of [`super::super::step_scan`]'s docs):
    /// −2 ln p(y) to 1e-6 of its change, every drift coefficient and 1σ to 1e-6 of the 1σ.
    /// Candidates through the measurement (acc-bias), the dynamics (drift-trend) and many
    /// columns at once (g2, q = 18) — the tracker's three paths. The same quantities by two
    /// routes, so only rounding separates them.
    #[test]
    fn a_signature_gives_the_extended_filters_evidence_and_coefficients() {
        use crate::simulate::{InjectedEffect, Scenario};
        let mut sc = Scenario::paper();
        sc.hours = 24.0;
        sc.rate_s = 60.0;
        sc.effects = vec![InjectedEffect::AccBias {
            b_mps2: [1e-4, -5e-5, 8e-5],
        }];
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let effects = [crate::catalog::paper()];
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let names = ["acc-bias", "drift-trend", "g2"];
        let candidates: Vec<&dyn estimator_core::effects::Effect> = names
            .iter()
            .map(|n| crate::catalog::builtin(n).unwrap())
            .collect();
        let lists: Vec<[&dyn estimator_core::effects::Effect; 2]> =
            candidates.iter().map(|&c| [effects[0], c]).collect();
        let extended: Vec<Option<Model<'_>>> = lists
            .iter()
            .map(|l| Some(build_model(prep.site, l, &cfg).unwrap()))
            .collect();
        let (x0, p0) = start_prior(&model, &prep, &prep.start_sigma());
        let (pass, sigs, _) = signatures(
            &model,
            &extended,
            &prep.measurements,
            &id.trajectory,
            &x0,
            &p0,
        )
        .unwrap();
        let base = neg2_log_evidence(&pass.innovations);
        let last = pass.states.last().unwrap();
        let n = model.dim();
        for ((name, c), sig) in names.iter().zip(&candidates).zip(&sigs) {
            let sig = sig.as_ref().unwrap();
            let prior: Vec<f64> = c.params().iter().map(|p| p.prior_sigma.powi(2)).collect();
            let (gain, beta, sigma) = marginal(&sig.score, &sig.info, &prior);
            let direct = with_extra(&prep, &effects, &cfg, &id, *c).unwrap();
            let change = base - direct.neg2_log_evidence;
            eprintln!(
                "{name}: gain {change:.3}, signature − extended {:.2e}",
                gain - change
            );
            assert!(
                (gain - change).abs() < 1e-6 * change.abs() + 1e-6,
                "{name}: signature gain {gain} vs extended {change}"
            );
            let moved = &sig.psi_final * &beta;
            let spread = &sig.psi_final * &sigma * sig.psi_final.transpose();
            for (k, (pname, value, sd)) in direct.drift.iter().enumerate() {
                let i = estimator_core::model::ANGLES + k;
                assert!(i < n);
                let v = last[i] + moved[i];
                let s = (pass.final_cov[(i, i)] + spread[(i, i)]).max(0.0).sqrt();
                assert!(
                    (v - value).abs() < 1e-6 * sd,
                    "{name} {pname}: {v} vs {value} (1σ {sd})"
                );
                assert!((s - sd).abs() < 1e-6 * sd, "{name} {pname}: σ {s} vs {sd}");
            }
        }
    }

    /// Every candidate of the built-in catalog replayed together (the constant ones linearised
    /// in one combined model) gets the signature it gets replayed alone, bit for bit: the
    /// combined linearisation adds only exact zeros to each candidate's columns. A recording
    /// with a temperature column, so the temperature effects' columns are not zero; drift-markov
    /// (a state of its own) is linearised on its own beside the group.
    #[test]
    fn a_combined_linearisation_gives_each_candidates_jacobians_bit_for_bit() {
        use crate::simulate::{InjectedEffect, Scenario};
        let mut sc = Scenario::paper();
        (sc.hours, sc.rate_s, sc.write_temp) = (8.0, 60.0, true);
        sc.effects = vec![InjectedEffect::AccBias {
            b_mps2: [1e-4, -5e-5, 8e-5],
        }];
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let current = [crate::catalog::paper()];
        let model = build_model(prep.site, &current, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let candidates = crate::catalog::builtin_candidates();
        let lists: Vec<[&dyn Effect; 2]> = candidates.iter().map(|&c| [current[0], c]).collect();
        let extended: Vec<Option<Model<'_>>> = lists
            .iter()
            .map(|l| Some(build_model(prep.site, l, &cfg).unwrap()))
            .collect();
        let groups = combinable(&model, &extended);
        assert_eq!(groups.len(), 1, "{groups:?}");
        assert_eq!(groups[0].len(), candidates.len() - 1, "{groups:?}");
        let (x0, p0) = start_prior(&model, &prep, &prep.start_sigma());
        let around = (&id.trajectory[..], &x0, &p0);
        let (_, together, _) =
            signatures_of(&model, &extended, &prep.measurements, around, true).unwrap();
        for (k, one) in extended.iter().enumerate() {
            let (_, alone, _) =
                signatures_of(&model, &[*one], &prep.measurements, around, true).unwrap();
            let (a, b) = (alone[0].as_ref().unwrap(), together[k].as_ref().unwrap());
            let name = candidates[k].name();
            assert_eq!(a.score, b.score, "{name}");
            assert_eq!(a.info, b.info, "{name}");
            assert_eq!(a.whitened, b.whitened, "{name}");
            assert_eq!(a.psi_final, b.psi_final, "{name}");
        }
    }
}
