//! The plan for the next run: which initial orientation (for how long) most improves what the
//! runs so far leave poorly determined.
//!
//! A candidate run is scored by its Fisher information: the filter linearised along the
//! noise-free trajectory from that orientation at the current parameters (the Cramér–Rao
//! bound of [`crate::identify::joint::run_bound_cov`]), fused with the information the runs so
//! far carry ([`crate::identify::joint::fuse`]). Two criteria:
//! - **weakest** (default): the largest 1σ of any combination of one gyro's four paper
//!   coefficients (D0, g·Dx, g·Dy, g·Dz), deg/h — the direction a static run leaves 12–19×
//!   weaker than the rest;
//! - **separate A,B**: the largest canonical correlation between the estimates of two effects'
//!   parameters (e.g. acc-bias and acc-scale).
//!
//! The weakest 1σ is scored on the **total** covariance, the one whose 1σ `identify` reports
//! (the separation on the noise-only one, [`Criterion::on_total`]): the bound
//! plus what each run's set-up leaves uncertain (latitude, clock rate, gravity, the vertical's
//! daily tilt, the daily drift — [`crate::identify::setup::uncertainty`] on the designed run's
//! noise-free measurements, each run's set-up marginalised as in
//! [`crate::identify::joint::fuse_with_setup`]). Where a set-up prior dominates a
//! coefficient, the noise bound alone would understate it and could rank designs wrongly.

use anyhow::{bail, Context as _};
use estimator_core::filter::ANGLE_PRIOR_SIGMA_RAD;
use estimator_core::model::{Model, ANGLES};
use estimator_core::{Effect, Sample, Site};
use nalgebra::DMatrix;
use rayon::prelude::*;

use crate::identify::joint::{fuse_with_setup, run_bound_cov, Run, RunSetup};
use crate::identify::{
    build_model, canonical_correlation, identify, nominal_trajectory, setup, smoothed_residuals,
    weak_combinations, Config, Estimate, Prepared,
};
use crate::quality::noise::NoiseFloor;

/// What a run to be made looks like.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Design {
    /// Initial orientation, ENU Euler angles (tx, ty, tz), deg.
    pub orientation_deg: [f64; 3],
    /// Duration, h.
    pub hours: f64,
    /// Sample interval, s.
    pub rate_s: f64,
    /// Raw accelerometer noise 1σ per axis, m/s².
    pub raw_sigma_mps2: [f64; 3],
}

/// What the plan minimises.
#[derive(Clone, Debug)]
pub enum Criterion {
    /// The weakest paper combination's 1σ, deg/h.
    Weakest,
    /// The canonical correlation between two parameter blocks (state indices after the angles).
    Separate {
        /// Names of the two effects.
        names: [String; 2],
        /// Their parameter indices.
        blocks: [Vec<usize>; 2],
    },
}

impl Criterion {
    /// `--separate A,B` against a model that contains both effects.
    pub fn separate(model: &Model<'_>, a: &str, b: &str) -> anyhow::Result<Self> {
        let block = |name: &str| -> anyhow::Result<Vec<usize>> {
            let Some(e) = model.effects().iter().position(|e| e.name() == name) else {
                bail!("--separate: effect {name:?} is not in the model (add it with --with)");
            };
            let (from, to) = (model.offset(e), model.offset(e + 1));
            Ok((from - ANGLES..to - ANGLES).collect())
        };
        Ok(Criterion::Separate {
            names: [a.to_string(), b.to_string()],
            blocks: [block(a)?, block(b)?],
        })
    }

    /// Whether candidates are ranked by the score of the total covariance (the weakest 1σ: what
    /// `identify` will report) or of the noise-only one (the separation of two effects: a
    /// property of the information; the set-up's common shifts — gravity moves acc-bias and
    /// acc-scale together — correlate the estimates on the total whatever the orientation).
    pub fn on_total(&self) -> bool {
        matches!(self, Criterion::Weakest)
    }

    /// The score a candidate is ranked by ([`Criterion::on_total`]).
    pub fn ranking(&self, c: &Candidate) -> f64 {
        if self.on_total() {
            c.score
        } else {
            c.noise_score
        }
    }

    /// The score of a parameter covariance (smaller is better); NaN if it cannot be computed.
    pub fn score(&self, model: &Model<'_>, cov: &DMatrix<f64>) -> f64 {
        match self {
            Criterion::Weakest => {
                let est = Estimate {
                    value: vec![0.0; cov.nrows()],
                    cov: cov.clone(),
                };
                weak_combinations(model, &est)
                    .iter()
                    .map(|w| w.sigma_degph)
                    .fold(f64::NAN, f64::max)
            }
            Criterion::Separate { blocks, .. } => {
                canonical_correlation(cov, &blocks[0], &blocks[1]).unwrap_or(f64::NAN)
            }
        }
    }
}

/// The orientations a plan considers: tx in steps of 45°, ty ∈ {−45°, 0°, 45°} and tz ∈ {0°, 90°}
/// (48 starts; with the Earth's turn they span the directions of gravity and of the pole in
/// platform axes that matter).
pub fn grid() -> Vec<[f64; 3]> {
    let mut out = vec![];
    for tz in [0.0, 90.0] {
        for ty in [-45.0, 0.0, 45.0] {
            for k in 0..8 {
                let tx = -135.0 + 45.0 * f64::from(k);
                out.push([tx, ty, tz]);
            }
        }
    }
    out
}

/// The measurements of a designed run (values are irrelevant to the information; their timing
/// and noise are those the run would have).
pub fn designed_prepared(site: Site, design: &Design, cfg: &Config) -> anyhow::Result<Prepared> {
    if !(design.hours > 0.0 && design.rate_s > 0.0 && design.rate_s <= cfg.period_s) {
        bail!(
            "a planned run needs hours > 0 and 0 < rate-s <= the filter period {} s",
            cfg.period_s
        );
    }
    let mut site = site;
    let theta_enu = design.orientation_deg.map(f64::to_radians);
    site.chart = site.chart_for_start(&theta_enu);
    // The simulator's own limit (Scenario::validate): `plan --hours 1e9` aborted on a 14-TB
    // allocation here.
    let samples_f = (design.hours * 3600.0 / design.rate_s).floor() + 1.0;
    if samples_f > 1e8 {
        bail!(
            "--hours/--rate-s: a planned run of {} h at {} s is {samples_f:.0} samples, too many (at most 1e8)",
            design.hours,
            design.rate_s
        );
    }
    let n = samples_f as usize;
    let samples: Vec<Sample> = (0..n)
        .map(|k| Sample {
            t_s: k as f64 * design.rate_s,
            specific_force: [0.0; 3],
            temp_c: f64::NAN,
        })
        .collect();
    let measurements = crate::quality::window_means(&samples, cfg.period_s, &design.raw_sigma_mps2);
    Ok(Prepared {
        site,
        measurements,
        noise: NoiseFloor {
            raw_sigma_mps2: design.raw_sigma_mps2,
            count: 0,
        },
        initial_angles: site.angles_to_chart(&theta_enu),
        initial_angle_sigma: [ANGLE_PRIOR_SIGMA_RAD; 3],
        alignment_sigma: cfg.setup.alignment_sigma(
            theta_enu == [0.0; 3] && site.chart == estimator_core::frames::Chart::Enu,
        ),
        findings: vec![],
    })
}

/// The parameter covariance (Cramér–Rao bound, wide prior included) of one designed run at
/// `params`.
pub fn design_cov(
    site: Site,
    effects: &[&dyn Effect],
    design: &Design,
    params: &[f64],
    cfg: &Config,
) -> anyhow::Result<DMatrix<f64>> {
    let prep = designed_prepared(site, design, cfg)?;
    let model = build_model(prep.site, effects, cfg)?;
    let run = Run {
        model: &model,
        prep: &prep,
    };
    run_bound_cov(&run, &prep.initial_angles, params)
        .with_context(|| format!("run from {:?} deg", design.orientation_deg))
}

/// The designed run's measurements made noise-free at `params`: each filter period's mean is the
/// model's prediction along the nominal trajectory (a recording with no noise, which a fit
/// reproduces exactly; the set-up's sensitivities are taken about it).
fn noise_free(model: &Model<'_>, prep: &mut Prepared, params: &[f64]) {
    let nominal = nominal_trajectory(model, &prep.measurements, &prep.initial_angles, params);
    for m in &mut prep.measurements {
        m.specific_force = [0.0; 3];
    }
    // Measured minus predicted of zero measurements: minus the prediction.
    let residuals = smoothed_residuals(model, &prep.measurements, &nominal);
    for (m, r) in prep.measurements.iter_mut().zip(residuals) {
        m.specific_force = r.map(|x| -x);
    }
}

/// What a designed run's set-up adds to its parameters' covariance: the share `identify` adds to
/// a recording's fit ([`setup::Uncertainty::setup_cov`]: latitude, clock rate, gravity, the
/// vertical's daily tilt, the daily drift; the start attitude is in the bound), computed as
/// `identify` computes it, on the run's noise-free measurements at `params` with the set-up
/// priors of `cfg`.
pub fn design_setup_cov(
    site: Site,
    effects: &[&dyn Effect],
    design: &Design,
    params: &[f64],
    cfg: &Config,
) -> anyhow::Result<DMatrix<f64>> {
    let mut prep = designed_prepared(site, design, cfg)?;
    let model = build_model(prep.site, effects, cfg)?;
    noise_free(&model, &mut prep, params);
    let id = identify(&model, &prep, cfg)
        .with_context(|| format!("the noise-free run from {:?} deg", design.orientation_deg))?;
    let unc = setup::uncertainty(effects, &prep, cfg, &id).with_context(|| {
        format!(
            "the set-up of the run from {:?} deg",
            design.orientation_deg
        )
    })?;
    Ok(unc.setup_cov)
}

/// One run's share of a joint estimate: its own parameter covariance (the run alone, from the
/// wide prior) and what its set-up adds to that ([`setup::Uncertainty::setup_cov`]).
pub type RunShare = (DMatrix<f64>, DMatrix<f64>);

/// The runs made so far: their joint estimate and each run's share.
#[derive(Clone, Debug)]
pub struct SoFar {
    /// The joint estimate (covariance without the set-up: noise only).
    pub estimate: Estimate,
    /// The total covariance now, every run's set-up marginalised, as `identify` reports it for
    /// these runs ([`crate::identify::joint::fuse_with_setup`]).
    pub total_cov: DMatrix<f64>,
    /// Per run, its own covariance and its set-up's share.
    pub runs: Vec<RunShare>,
}

/// The runs' shares fused ([`fuse_with_setup`], from the prior `p0`): the total covariance and
/// the noise-only one.
fn fused(shares: &[RunShare], p0: &DMatrix<f64>) -> anyhow::Result<(DMatrix<f64>, DMatrix<f64>)> {
    let posteriors: Vec<Estimate> = shares
        .iter()
        .map(|(cov, _)| Estimate {
            value: vec![0.0; p0.nrows()],
            cov: cov.clone(),
        })
        .collect();
    let setups: Vec<RunSetup> = shares
        .iter()
        .map(|(_, cov)| RunSetup {
            cov: cov.clone(),
            shift: vec![],
        })
        .collect();
    let (total, noise) = fuse_with_setup(&posteriors, &setups, p0)?;
    Ok((total.cov, noise))
}

/// One candidate of a plan.
#[derive(Clone, Debug)]
pub struct Candidate {
    /// The run(s) proposed: one for a next run, two for a first pair.
    pub designs: Vec<Design>,
    /// Covariance of the parameters after the proposed run(s), noise only (the Cramér–Rao
    /// bound, start attitude estimated at its prior): `identify`'s joint "fit 1σ".
    pub cov: DMatrix<f64>,
    /// The total covariance after: `cov` plus every run's set-up share, the 1σ `identify`
    /// reports as the headline.
    pub total_cov: DMatrix<f64>,
    /// The criterion's value after, on the total covariance (the weakest 1σ is ranked by it).
    pub score: f64,
    /// The criterion's value after on the noise-only covariance (two effects' separation is
    /// ranked by it).
    pub noise_score: f64,
}

impl Candidate {
    /// The candidate after fusing `shares`, every run's own covariance and set-up share (each
    /// from the prior `p0`).
    fn new(
        designs: Vec<Design>,
        shares: &[RunShare],
        p0: &DMatrix<f64>,
        eval: (&Model<'_>, &Criterion),
    ) -> anyhow::Result<Self> {
        let (total_cov, cov) = fused(shares, p0)?;
        let (model, criterion) = eval;
        Ok(Candidate {
            designs,
            score: criterion.score(model, &total_cov),
            noise_score: criterion.score(model, &cov),
            cov,
            total_cov,
        })
    }
}

/// The candidates, best first ([`Criterion::ranking`]): the next run after `before` (the runs
/// so far, a posterior from the model's wide prior `p0`), or with `before = None` the best first
/// pair.
pub fn rank(
    model: &Model<'_>,
    effects: &[&dyn Effect],
    criterion: &Criterion,
    before: Option<&SoFar>,
    template: &Design,
    params: &[f64],
    cfg: &Config,
) -> anyhow::Result<Vec<Candidate>> {
    let n = model.dim() - ANGLES;
    let (_, p0_full) = crate::identify::wide_prior(model, &vec![0.0; model.dim()], &[0.0; 3]);
    let p0 = p0_full.view((ANGLES, ANGLES), (n, n)).into_owned();
    let designs: Vec<Design> = grid()
        .into_iter()
        .map(|o| Design {
            orientation_deg: o,
            ..*template
        })
        .collect();
    // One bound and one set-up share per orientation, on all cores.
    let site = *model.site();
    let shares = designs
        .par_iter()
        .map(|d| {
            let cov = design_cov(site, effects, d, params, cfg)?;
            Ok((cov, design_setup_cov(site, effects, d, params, cfg)?))
        })
        .collect::<anyhow::Result<Vec<RunShare>>>()?;
    let eval = (model, criterion);
    let mut out = vec![];
    match before {
        Some(b) => {
            for (d, share) in designs.iter().zip(&shares) {
                let mut runs = b.runs.clone();
                runs.push(share.clone());
                out.push(Candidate::new(vec![*d], &runs, &p0, eval)?);
            }
        }
        None => {
            for i in 0..designs.len() {
                for j in i + 1..designs.len() {
                    let runs = [shares[i].clone(), shares[j].clone()];
                    let pair = vec![designs[i], designs[j]];
                    out.push(Candidate::new(pair, &runs, &p0, eval)?);
                }
            }
        }
    }
    out.sort_by(|a, b| criterion.ranking(a).total_cmp(&criterion.ranking(b)));
    Ok(out)
}
