//! Joint identification: one set of parameters from several runs of the same system.
//!
//! Each run keeps its own site and chart, initial attitude (a nuisance the run's own smoother
//! carries), start time, noise floor and temperature; the parameters are shared. Given a joint
//! estimate p̂, each run's linearised smoother about its nominal trajectory at p̂ yields the
//! posterior N(p_r, P_r) of the parameters from the common prior N(0, P0) and that run's data
//! alone, with the run's angles marginalised. The runs' data are independent given p, so in the
//! linearised problem the information adds up exactly (the prior counted once):
//!
//! ```text
//! Λ = P0⁻¹ + Σ_r (P_r⁻¹ − P0⁻¹),   p̂ = Λ⁻¹ Σ_r P_r⁻¹ p_r      (prior mean 0)
//! ```
//!
//! **Each run's set-up is a nuisance of the joint fit.** A run's latitude, clock rate and
//! gravity (estimated where its data can, [`super::setup::settle`]), the vertical's daily tilt
//! and the daily drift are the run's own, independent between runs. Linearised, the parameters'
//! posterior from run r with its set-up s_r marginalised is exactly N(p_r(ŝ_r), P_r + C_r):
//! the fit at the set-up's posterior ŝ_r, widened by `C_r = S_r V_r S_rᵀ` (S_r the coefficients'
//! sensitivity to s_r, V_r its posterior covariance — [`super::setup::Uncertainty::setup_cov`]).
//! Fusing these marginal posteriors as above is the joint fit with every run's set-up estimated
//! along: a run whose set-up leaves a coefficient uncertain weighs less on it, and the fused
//! covariance is the total one. The same fusion without the C_r gives the noise-only covariance
//! (the set-ups exactly known), the one the Cramér–Rao bound is compared with.
//!
//! Iterating (each run relinearised about p̂) is Gauss–Newton for the joint likelihood. Each run
//! is first identified alone ([`super::identify`], with its fall-backs) for a start. Effects with
//! Gauss–Markov states (time-varying parameters) are per run and cannot be shared: refused.

use anyhow::{bail, Context as _};
use estimator_core::effects::Param;
use estimator_core::model::{Model, ANGLES};
use estimator_core::Residual;
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::smoother::linearised_pass;
use super::{
    identify, nominal_trajectory, weak_combinations, wide_prior, Config, Estimate, Identification,
    Prepared, WeakCombination,
};

/// Gauss–Newton iterations of the joint fit after the runs' own fits (the second changes the
/// estimate by far less than 1σ on the paper's scenario).
pub const JOINT_ITERATIONS: usize = 3;

/// One run of a joint identification: its model (site and chart are the run's own) and data.
pub struct Run<'a, 'm> {
    /// The run's model: the same effects for every run, the run's own site.
    pub model: &'a Model<'m>,
    /// The run's prepared measurements.
    pub prep: &'a Prepared,
}

/// What the joint fit says about one run. Whether the shared model explains the run is its own
/// fit's consistency at its settled set-up (the coefficients its own); whether the run's
/// coefficients agree with the joint ones is [`crate::consistency::run_agreement`]. (A pass with the joint
/// estimate as the parameters' prior at the run's settled set-up is no test of either: where
/// the run's set-up moves a coefficient the run's data pin at that set-up, the joint estimate
/// lies many of its noise-only 1σ away, and its innovations fail whiteness on clean runs.)
#[derive(Clone, Debug)]
pub struct RunFit {
    /// The run identified alone, at its settled set-up.
    pub alone: Identification,
    /// Smoothed initial angles of the run's last relinearisation, in the run's chart, rad.
    pub initial_angles: [f64; 3],
    /// What the run's set-up leaves uncertain, marginalised in the joint fit.
    pub setup: RunSetup,
    /// The run's own posterior at the joint estimate (its data alone, its set-up as settled).
    pub own: Estimate,
}

impl RunFit {
    /// How a shift of this run's estimate moves the joint one, `Λ⁻¹ (P_r + C_r)⁻¹` (the run's
    /// weight in the fusion, `joint` its result; see the module docs).
    pub fn weight(&self, joint: &Estimate) -> DMatrix<f64> {
        let t = &self.own.cov + &self.setup.cov;
        let t = (&t + t.transpose()) * 0.5;
        match t.clone().cholesky() {
            Some(c) => &joint.cov * c.inverse(),
            // Not reached: the fusion refuses such a posterior. A shift then counts in full.
            None => DMatrix::identity(t.nrows(), t.nrows()),
        }
    }
    /// Innovations of the run's own fit.
    pub fn innovations(&self) -> &[Residual] {
        &self.alone.innovations
    }
    /// Measured minus predicted along the run's own fitted trajectory, m/s².
    pub fn residuals(&self) -> &[[f64; 3]] {
        &self.alone.smoothed_residuals
    }
    /// RMS of the run's residual per axis on its floor's scale, m/s² ([`Prepared::residual_rms_mps2`]).
    pub fn residual_rms_mps2(&self, prep: &Prepared) -> [f64; 3] {
        prep.residual_rms_mps2(self.residuals())
    }
}

/// What a run's set-up leaves uncertain in the run's own estimate: the joint fit marginalises
/// it (see the module docs).
#[derive(Clone, Debug)]
pub struct RunSetup {
    /// Covariance the set-up adds to the run's estimate ([`super::setup::Uncertainty::setup_cov`]).
    pub cov: DMatrix<f64>,
    /// How far marginalising the slow drifts moved the run's estimate
    /// ([`super::setup::Uncertainty::drift_shift`]; empty: none): kept when the run is
    /// relinearised.
    pub shift: Vec<f64>,
}

impl RunSetup {
    /// A set-up taken as exactly known, for `n` parameters.
    pub fn known(n: usize) -> Self {
        RunSetup {
            cov: DMatrix::zeros(n, n),
            shift: vec![],
        }
    }
}

/// The joint estimate and each run's fit.
#[derive(Clone, Debug)]
pub struct JointIdentification {
    /// The shared parameters (name, unit, prior), in state order after the angles.
    pub params: Vec<Param>,
    /// Joint estimate, every run's set-up marginalised, and its total covariance.
    pub estimate: Estimate,
    /// Covariance with every run's set-up exactly known: noise only ("fit 1σ").
    pub noise_cov: DMatrix<f64>,
    /// Per run, in the order given.
    pub runs: Vec<RunFit>,
    /// Weakest combinations of the paper's coefficients in the joint information.
    pub weak: Vec<WeakCombination>,
}

/// Information form of a Gaussian: (Λ, η) with Λ = P⁻¹, η = P⁻¹·m.
fn information(cov: &DMatrix<f64>, mean: &[f64]) -> anyhow::Result<(DMatrix<f64>, DVector<f64>)> {
    let sym = (cov + cov.transpose()) * 0.5;
    let Some(chol) = sym.cholesky() else {
        bail!("a run's parameter covariance is not positive definite");
    };
    let lambda = chol.inverse();
    let eta = &lambda * DVector::from_row_slice(mean);
    Ok((lambda, eta))
}

/// Fuses the runs' posteriors (each from the prior `p0`, mean 0) into the joint one.
pub fn fuse(posteriors: &[Estimate], p0: &DMatrix<f64>) -> anyhow::Result<Estimate> {
    let n = p0.nrows();
    let (prior_info, _) = information(p0, &vec![0.0; n])?;
    let mut lambda = prior_info.clone();
    let mut eta = DVector::zeros(n);
    for post in posteriors {
        let (l, e) = information(&post.cov, &post.value)?;
        lambda += l - &prior_info;
        eta += e;
    }
    let sym = (&lambda + lambda.transpose()) * 0.5;
    let Some(chol) = sym.cholesky() else {
        bail!("the joint information is not positive definite");
    };
    let value = chol.solve(&eta);
    Ok(Estimate {
        value: value.as_slice().to_vec(),
        cov: chol.inverse(),
    })
}

/// The runs' posteriors fused twice ([`fuse`]): with each run's set-up marginalised (its
/// covariance widened by `setups[r].cov`, see the module docs) — the joint estimate and its total
/// covariance — and with the set-ups exactly known — the noise-only covariance. The runs' set-ups
/// are independent (each run's own logger, its own days; a latitude common to runs at one site
/// is not correlated here).
pub fn fuse_with_setup(
    posteriors: &[Estimate],
    setups: &[RunSetup],
    p0: &DMatrix<f64>,
) -> anyhow::Result<(Estimate, DMatrix<f64>)> {
    let noise = fuse(posteriors, p0)?;
    let widened: Vec<Estimate> = posteriors
        .iter()
        .zip(setups)
        .map(|(p, s)| Estimate {
            value: p.value.clone(),
            cov: &p.cov + &s.cov,
        })
        .collect();
    Ok((fuse(&widened, p0)?, noise.cov))
}

/// The parameter block of the wide prior (the same for every run).
fn parameter_prior(model: &Model<'_>) -> DMatrix<f64> {
    let (_, p0) = wide_prior(model, &vec![0.0; model.dim()], &[0.0; 3]);
    p0.view(
        (ANGLES, ANGLES),
        (model.dim() - ANGLES, model.dim() - ANGLES),
    )
    .into_owned()
}

/// One run linearised about its trajectory at `params` from `angles0`: its posterior from the
/// wide prior, and its smoothed initial angles.
fn run_posterior(
    run: &Run<'_, '_>,
    angles0: &[f64; 3],
    params: &[f64],
) -> anyhow::Result<(Estimate, [f64; 3])> {
    let (model, meas) = (run.model, &run.prep.measurements);
    let n = model.dim();
    let nominal = nominal_trajectory(model, meas, angles0, params);
    let mut start = vec![0.0; n];
    start[..ANGLES].copy_from_slice(&run.prep.initial_angles);
    let (x0, p0) = wide_prior(model, &start, &run.prep.start_sigma());
    let pass = linearised_pass(model, meas, &nominal, &x0, &p0, true)?;
    let (Some(first), Some(last)) = (pass.states.first(), pass.states.last()) else {
        bail!("the smoother returned no states");
    };
    let estimate = Estimate {
        value: last.as_slice()[ANGLES..].to_vec(),
        cov: pass
            .final_cov
            .view((ANGLES, ANGLES), (n - ANGLES, n - ANGLES))
            .into_owned(),
    };
    Ok((estimate, [first[0], first[1], first[2]]))
}

/// Identifies one set of parameters from several runs (see the module docs), each run's set-up
/// taken as exactly known.
pub fn identify_joint(runs: &[Run<'_, '_>], cfg: &Config) -> anyhow::Result<JointIdentification> {
    identify_joint_from(runs, fit_alone(runs, cfg), &[])
}

/// Each run identified alone ([`identify`], with its fall-backs), on all cores: the joint fit's
/// start. An error names its run.
pub fn fit_alone(runs: &[Run<'_, '_>], cfg: &Config) -> Vec<anyhow::Result<Identification>> {
    runs.par_iter()
        .enumerate()
        .map(|(r, run)| {
            identify(run.model, run.prep, cfg).with_context(|| format!("run {}", r + 1))
        })
        .collect()
}

/// [`identify_joint`] from the runs' own fits, made already ([`fit_alone`], or at each run's
/// settled set-up), with each run's set-up marginalised (`setups[r]`; empty: every set-up
/// exactly known).
pub fn identify_joint_from(
    runs: &[Run<'_, '_>],
    fits: Vec<anyhow::Result<Identification>>,
    setups: &[RunSetup],
) -> anyhow::Result<JointIdentification> {
    let Some(first) = runs.first() else {
        bail!("no runs to identify from");
    };
    if first.model.dynamic_states().len() > ANGLES {
        bail!("effects with Gauss-Markov states (drift-markov) vary within each run and cannot be shared between runs; identify those runs one at a time");
    }
    let p0 = parameter_prior(first.model);
    let known = vec![RunSetup::known(p0.nrows()); runs.len()];
    let setups = if setups.is_empty() { &known } else { setups };
    if setups.len() != runs.len() {
        bail!("{} set-ups for {} runs", setups.len(), runs.len());
    }
    let mut alone = Vec::with_capacity(runs.len());
    let mut posteriors = Vec::with_capacity(runs.len());
    let mut angles = Vec::with_capacity(runs.len());
    for (run, id) in runs.iter().zip(fits) {
        let id = id?;
        posteriors.push(id.best().clone());
        let a = id
            .trajectory
            .first()
            .map_or(run.prep.initial_angles, |x| [x[0], x[1], x[2]]);
        angles.push(a);
        alone.push(id);
    }
    let (mut joint, mut noise_cov) = fuse_with_setup(&posteriors, setups, &p0)?;
    for _ in 0..JOINT_ITERATIONS {
        for (r, run) in runs.iter().enumerate() {
            let (mut post, a) = run_posterior(run, &angles[r], &joint.value)
                .with_context(|| format!("joint fit, run {}", r + 1))?;
            for (v, d) in post.value.iter_mut().zip(&setups[r].shift) {
                *v += d;
            }
            posteriors[r] = post;
            angles[r] = a;
        }
        (joint, noise_cov) = fuse_with_setup(&posteriors, setups, &p0)?;
    }
    let mut fits = Vec::with_capacity(runs.len());
    let own = posteriors.into_iter().zip(setups.iter().cloned());
    for ((alone, initial_angles), (own, setup)) in alone.into_iter().zip(angles).zip(own) {
        fits.push(RunFit {
            alone,
            initial_angles,
            setup,
            own,
        });
    }
    let weak = weak_combinations(
        first.model,
        &Estimate {
            value: joint.value.clone(),
            cov: noise_cov.clone(),
        },
    );
    Ok(JointIdentification {
        params: (ANGLES..first.model.dim())
            .map(|i| first.model.param(i))
            .collect(),
        estimate: joint,
        noise_cov,
        runs: fits,
        weak,
    })
}

/// The joint Cramér–Rao bound (1σ per parameter) at `params`: each run's filter linearised along
/// its noise-free trajectory, the information fused as in [`fuse`].
pub fn joint_bound(runs: &[Run<'_, '_>], params: &[f64]) -> anyhow::Result<Vec<f64>> {
    let Some(first) = runs.first() else {
        bail!("no runs");
    };
    let p0 = parameter_prior(first.model);
    let mut posteriors = Vec::with_capacity(runs.len());
    for run in runs {
        let cov = run_bound_cov(run, &run.prep.initial_angles, params)?;
        posteriors.push(Estimate {
            value: vec![0.0; params.len()],
            cov,
        });
    }
    let fused = fuse(&posteriors, &p0)?;
    Ok((0..params.len()).map(|k| fused.sigma(k)).collect())
}

/// One run's parameter covariance from its filter linearised along the noise-free trajectory at
/// `params` (the run's Cramér–Rao bound, the wide prior included).
pub fn run_bound_cov(
    run: &Run<'_, '_>,
    angles0: &[f64; 3],
    params: &[f64],
) -> anyhow::Result<DMatrix<f64>> {
    let (model, meas) = (run.model, &run.prep.measurements);
    let n = model.dim();
    let mut start = angles0.to_vec();
    start.extend_from_slice(params);
    let (x0, p0) = wide_prior(model, &start, &run.prep.start_sigma());
    let cov = super::smoother::noise_free_covariance(model, meas, &start, &x0, &p0)?;
    Ok(cov
        .view((ANGLES, ANGLES), (n - ANGLES, n - ANGLES))
        .into_owned())
}
