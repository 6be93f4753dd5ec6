//! A gyro drift step: the constant drift of the gyro axes changes at one time t₀ (a rotor or
//! suspension event). In the accelerometers it is a kink, not a jump: the platform's turn rate
//! changes, so the tilt bends. Found as an explanation of a misfit: the model plus a step of
//! unknown size per axis at t₀, weighed by the marginal likelihood of the measurements and
//! profiled over t₀.
//!
//! The step sizes enter linearly and are small, so each t₀ costs one forward pass of the filter
//! linearised about the fitted trajectory (the sizes' prior 1σ [`PRIOR_SIGMA_DEGPH`] integrated
//! out); t₀ runs over the measurement times every [`COARSE_STEP_H`] from one hour after the start
//! to one hour before the end, then every measurement within one coarse step of the best. The
//! search over N times is paid for: the evidence gain is counted after 2 ln N (the
//! look-elsewhere penalty of N independent tries).

use estimator_core::effects::{Context, Effect, Param, Partials};
use estimator_core::units::S_PER_H;
use nalgebra::{DVector, Vector3};
use serde::Serialize;

use crate::diagnose::select::{Member, Profiled};
use crate::identify::{
    build_model, neg2_log_evidence, start_prior, Config, Identification, Prepared,
};

/// Prior 1σ of each axis' step, deg/h.
pub(crate) const PRIOR_SIGMA_DEGPH: f64 = 0.01;
/// Spacing of the coarse profile over t₀, h.
pub(crate) const COARSE_STEP_H: f64 = 0.5;

pub(crate) const PARAMS: [Param; 3] = [
    Param {
        name: "DSX",
        unit: "deg/h",
        prior_sigma: PRIOR_SIGMA_DEGPH,
    },
    Param {
        name: "DSY",
        unit: "deg/h",
        prior_sigma: PRIOR_SIGMA_DEGPH,
    },
    Param {
        name: "DSZ",
        unit: "deg/h",
        prior_sigma: PRIOR_SIGMA_DEGPH,
    },
];

/// The drift step at `t0_s`: `w_i += s_i` for t ≥ t₀ (deg/h).
#[derive(Clone, Copy, Debug)]
pub(crate) struct DriftStep {
    /// Time of the step, s.
    pub t0_s: f64,
}

impl Effect for DriftStep {
    fn name(&self) -> &'static str {
        "drift-step"
    }
    fn about(&self) -> &'static str {
        "A step of the gyros' constant drift at one time (a rotor or suspension event): a kink in \
         the accelerometer signal, not a jump."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let on = if ctx.t_s >= self.t0_s { 1.0 } else { 0.0 };
        for i in 0..3 {
            out.value[i] += p[i] * on;
            out.d_params[i] = Vector3::ith(i, on);
        }
    }
    fn touches_drift(&self) -> bool {
        true
    }
    fn touches_accel(&self) -> bool {
        false
    }
}

/// The best drift step found.
#[derive(Clone, Debug, Serialize)]
pub struct DriftStepFit {
    /// Time of the step, s (a measurement's time: the effect is made for it).
    pub t0_s: f64,
    /// Time of the step, h.
    pub t0_h: f64,
    /// Step per gyro axis X, Y, Z, deg/h.
    pub size_degph: [f64; 3],
    /// Their 1σ, deg/h.
    pub sigma_degph: [f64; 3],
    /// −2 ln L of the fit minus that with the step, less 2 ln N for the N coarse times tried.
    pub evidence_gain: f64,
    /// Coarse times tried.
    pub times_tried: usize,
    /// Every time tried, each linearised about the fit profiled (its gain charged the same
    /// penalty): a step at another time the data do not rule out is a rival of its own.
    #[serde(skip)]
    pub members: Vec<Member>,
}

impl DriftStepFit {
    /// The axis whose step stands out most (index, in its 1σ).
    pub fn main_axis(&self) -> (usize, f64) {
        (0..3)
            .map(|i| (i, (self.size_degph[i] / self.sigma_degph[i]).abs()))
            .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a })
    }
}

/// The model plus an effect, in one forward pass linearised about a fit.
#[derive(Clone)]
pub(crate) struct Extra {
    /// −2 ln L of the pass.
    pub neg2_log_evidence: f64,
    /// The paper's drift coefficients under it: name, value, 1σ (as [`Refit::drift`]).
    ///
    /// [`Refit::drift`]: crate::diagnose::select::Refit::drift
    pub drift: Vec<(&'static str, f64, f64)>,
}

/// [`with_extra`] of each of `extras` (`None` where its model cannot be built), from one replay
/// of the current filter carrying every extra's signature ([`super::score::signatures_kept`])
/// instead of one extended pass each. The model is linear in an extra's parameters about the
/// fit, so the two routes give the same numbers to rounding (tested): the evidence from the
/// score and information ([`super::step_scan::marginal`]), the coefficients moved by Ψ_N β̂ and
/// their variance grown by Ψ_N Σ Ψ_Nᵀ ([`super::step_scan::Final`]). Each extra still costs the
/// extended model's propagation at every update; what is saved is the extended covariance's
/// algebra (a misfitting 60-h `diagnose`: ~4 % of its CPU time). The extras are split among the
/// pool's threads, a replay each.
pub(crate) fn with_each(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
    extras: &[&(dyn Effect + Sync)],
) -> Vec<Option<Extra>> {
    use rayon::prelude::*;
    let per_thread = extras.len().div_ceil(rayon::current_num_threads()).max(1);
    extras
        .par_chunks(per_thread)
        .flat_map_iter(|part| {
            let part: Vec<&dyn Effect> = part.iter().map(|x| *x as &dyn Effect).collect();
            with_each_replayed(prep, effects, cfg, id, &part)
        })
        .collect()
}

/// [`with_each`] from one replay.
fn with_each_replayed(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
    extras: &[&dyn Effect],
) -> Vec<Option<Extra>> {
    let none = || extras.iter().map(|_| None).collect();
    let Ok(model) = build_model(prep.site, effects, cfg) else {
        return none();
    };
    let lists: Vec<Vec<&dyn Effect>> = extras
        .iter()
        .map(|x| effects.iter().copied().chain([*x]).collect())
        .collect();
    let extended: Vec<Option<estimator_core::model::Model<'_>>> = lists
        .iter()
        .map(|l| build_model(prep.site, l, cfg).ok())
        .collect();
    let (x0, p0) = start_prior(&model, prep, &prep.start_sigma());
    let nominal = (&id.trajectory[..], &x0, &p0);
    let replay =
        super::score::signatures_kept(&model, &extended, &prep.measurements, nominal, false);
    let Ok((pass, sigs, _)) = replay else {
        return none();
    };
    let Some(last) = pass.states.last() else {
        return none();
    };
    let a = estimator_core::model::ANGLES;
    let n = model.dim();
    let rows: Vec<usize> = (0..12.min(id.params.len())).map(|k| a + k).collect();
    let on = super::step_scan::Final {
        base: neg2_log_evidence(&pass.innovations),
        last,
        cov: &pass.final_cov,
        id,
        rows: &rows,
    };
    extended
        .iter()
        .zip(sigs)
        .map(|(m, sig)| {
            let (m, sig) = (m.as_ref()?, sig?);
            let prior: Vec<f64> = (n..m.dim())
                .map(|i| m.param(i).prior_sigma.powi(2))
                .collect();
            let psi = sig.psi_final.select_rows(&rows);
            Some(on.with(&sig.score, &sig.info, &prior, &psi))
        })
        .collect()
}

/// `extra`, appended to the model, estimated with the rest in one forward pass linearised about
/// `id`'s trajectory (the parameters enter linearly and are small; the last filtered state is
/// their estimate from the whole run).
pub(crate) fn with_extra(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
    extra: &dyn Effect,
) -> Option<Extra> {
    let mut list: Vec<&dyn Effect> = effects.iter().map(|e| *e as &dyn Effect).collect();
    list.push(extra);
    let model = build_model(prep.site, &list, cfg).ok()?;
    let n = model.dim();
    let nominal = extended(id, n);
    let (x0, p0) = start_prior(&model, prep, &prep.start_sigma());
    let pass = crate::identify::smoother::linearised_pass(
        &model,
        &prep.measurements,
        &nominal,
        &x0,
        &p0,
        false,
    )
    .ok()?;
    let last = pass.states.last()?;
    let sd = |i: usize| pass.final_cov[(i, i)].max(0.0).sqrt();
    let a = estimator_core::model::ANGLES;
    Some(Extra {
        neg2_log_evidence: neg2_log_evidence(&pass.innovations),
        drift: (0..12.min(id.params.len()))
            .map(|k| (id.params[k].name, last[a + k], sd(a + k)))
            .collect(),
    })
}

/// The drift step that best explains the measurements beyond the fit `id` of `effects` (see the
/// module docs); `None` when the run is too short (under 3 h) or every pass fails.
pub fn profile(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
) -> Option<DriftStepFit> {
    use rayon::prelude::*;
    let meas = &prep.measurements;
    let end_s = meas.last()?.t_s;
    if id.trajectory.len() != meas.len() + 1 || end_s < 3.0 * S_PER_H {
        return None;
    }
    let base = neg2_log_evidence(&id.innovations);
    let mut coarse: Vec<f64> = vec![];
    let mut next = S_PER_H;
    for m in meas {
        if m.t_s >= next && m.t_s <= end_s - S_PER_H {
            coarse.push(m.t_s);
            next = m.t_s + COARSE_STEP_H * S_PER_H;
        }
    }
    // Every time at once from one replay (`step_scan`) where it fits in memory; else one
    // forward pass of the extended filter per time (the same numbers, see its test).
    let scan = super::step_scan::every_update(prep, effects, cfg, id);
    let eval = |ts: &[f64]| -> Vec<(f64, Extra)> {
        match scan.as_deref() {
            Some(all) => ts
                .iter()
                .filter_map(|&t| {
                    // The update whose interval starts at t: the step is on from there.
                    let j = all.partition_point(|u| u.t_prev_s < t);
                    all.get(j).map(|u| (t, u.extra.clone()))
                })
                .collect(),
            None => ts
                .par_iter()
                .filter_map(|&t| {
                    with_extra(prep, effects, cfg, id, &DriftStep { t0_s: t }).map(|e| (t, e))
                })
                .collect(),
        }
    };
    let best = |v: &[(f64, Extra)]| {
        v.iter()
            .min_by(|a, b| a.1.neg2_log_evidence.total_cmp(&b.1.neg2_log_evidence))
            .map(|(t, _)| *t)
    };
    let mut tried = eval(&coarse);
    let t_c = best(&tried)?;
    let fine: Vec<f64> = meas
        .iter()
        .map(|m| m.t_s)
        .filter(|t| (t - t_c).abs() <= COARSE_STEP_H * S_PER_H)
        .collect();
    let fine = eval(&fine);
    let t0 = best(&fine)?;
    tried.extend(fine);
    let (f, size, sigma) = refit(prep, effects, cfg, id, t0)?;
    let penalty = 2.0 * (coarse.len().max(1) as f64).ln();
    Some(DriftStepFit {
        t0_s: t0,
        t0_h: t0 / S_PER_H,
        size_degph: size,
        sigma_degph: sigma,
        evidence_gain: base - f - penalty,
        times_tried: coarse.len(),
        members: tried
            .into_iter()
            .map(|(t, e)| Member {
                profiled: Profiled::StepAtS(t),
                evidence_gain: base - e.neg2_log_evidence - penalty,
                drift: e.drift,
            })
            .collect(),
    })
}

/// The model with the step at `t0_s` refitted by Gauss–Newton from `id`'s trajectory (the
/// profile's pass is linearised about a fit that bent to absorb the step): −2 ln L and the sizes
/// with their 1σ.
fn refit(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
    t0_s: f64,
) -> Option<(f64, [f64; 3], [f64; 3])> {
    let step = DriftStep { t0_s };
    let mut list: Vec<&dyn Effect> = effects.iter().map(|e| *e as &dyn Effect).collect();
    list.push(&step);
    let model = build_model(prep.site, &list, cfg).ok()?;
    let n = model.dim();
    let (x0, p0) = start_prior(&model, prep, &prep.start_sigma());
    let fit = crate::identify::gauss_newton_final(
        &model,
        &prep.measurements,
        extended(id, n),
        &x0,
        &p0,
        2,
        cfg.smoother_iterations + crate::identify::GN_EXTRA_ITERATIONS,
    )
    .ok()?;
    let last = fit.states.last()?;
    let size = [0, 1, 2].map(|i| last[n - 3 + i]);
    let sigma = [0, 1, 2].map(|i| fit.final_cov[(n - 3 + i, n - 3 + i)].max(0.0).sqrt());
    Some((neg2_log_evidence(&fit.innovations), size, sigma))
}

/// `effects` plus the step, and the model refitted with it: the repair of a run whose misfit a
/// drift step explains best (`driftid identify`).
pub fn repair<'c>(
    catalog: &'c crate::catalog::Catalog,
    prep: &Prepared,
    effects: &[&'c dyn Effect],
    cfg: &Config,
    step: &DriftStepFit,
) -> anyhow::Result<(Vec<&'c dyn Effect>, Identification)> {
    let mut list = effects.to_vec();
    list.push(Profiled::StepAtS(step.t0_s).effect(catalog));
    let model = build_model(prep.site, &list, cfg)?;
    let id = crate::identify::identify(&model, prep, cfg)?;
    Ok((list, id))
}

/// The drift step as a candidate of a diagnosis rung, on the evidence scale of the catalog's
/// refits ([`crate::diagnose::select::refit_effect`]): profiled over its time, then the model
/// with it converged, its evidence gain charged the look-elsewhere penalty of the times tried.
/// `None` when a step is in the model already, the run is too short, or it gains nothing.
pub fn candidate(
    prep: &Prepared,
    effects: &[&dyn Effect],
    id: &Identification,
    cfg: &crate::diagnose::DiagnoseConfig,
) -> Option<crate::diagnose::select::Refit> {
    if effects.iter().any(|e| e.name() == "drift-step") {
        return None;
    }
    cfg.progress.note(|| "profiling a gyro drift step".into());
    let fit = profile(prep, effects, &cfg.identify, id)?;
    if fit.evidence_gain <= crate::diagnose::select::MIN_EVIDENCE_GAIN {
        return None;
    }
    let penalty = 2.0 * (fit.times_tried.max(1) as f64).ln();
    // Weighed with a step of its own; the catalog owns the one a rung adopts (`Profiled::effect`).
    let step = DriftStep { t0_s: fit.t0_s };
    let mut r = crate::diagnose::select::refit_effect(prep, (effects, id), &step, penalty, cfg)?;
    r.profiled = Some(Profiled::StepAtS(fit.t0_s));
    r.members = fit.members;
    Some(r)
}

impl DriftStepFit {
    /// The finding of a step repaired by modelling it: when, how large, the evidence.
    pub fn repaired(&self) -> crate::quality::Finding {
        crate::quality::Finding {
            kind: crate::quality::Kind::DriftStep,
            message: format!(
                "the gyro drift steps at t = {:.2} h by {} deg/h (evidence gain {:.1} after the look-elsewhere penalty of {} times tried, more than any other explanation); modelled from then on (`drift-step`)",
                self.t0_h,
                self.sizes(),
                self.evidence_gain,
                self.times_tried
            ),
            start_s: Some(self.t0_s),
            end_s: None,
            samples: 0,
            action: crate::quality::Action::Repaired,
        }
    }

    /// "X a ± σ, Y …, Z …" (deg/h).
    fn sizes(&self) -> String {
        (0..3)
            .map(|i| {
                format!(
                    "{} {}",
                    ["X", "Y", "Z"][i],
                    crate::format::pm(self.size_degph[i], self.sigma_degph[i])
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// `id`'s trajectory with the step sizes (the last states of an `n`-state model) at zero.
fn extended(id: &Identification, n: usize) -> Vec<DVector<f64>> {
    id.trajectory
        .iter()
        .map(|x| DVector::from_fn(n, |i, _| if i < x.len() { x[i] } else { 0.0 }))
        .collect()
}

impl DriftStepFit {
    /// Whether the step explains the data: an evidence gain above
    /// [`crate::diagnose::select::MIN_EVIDENCE_GAIN`] that beats every alternative explanation
    /// by [`crate::diagnose::alternatives::PLAUSIBLE_MARGIN`] (a Gauss–Markov wander or a trend
    /// is partly followed by a step too: on such runs a step gained 1.3e6 where `drift-markov`
    /// gained 2.0e6).
    pub(crate) fn beats(
        &self,
        alternatives: &[crate::diagnose::alternatives::Alternative],
    ) -> bool {
        let best = alternatives
            .iter()
            .map(|a| a.evidence_gain)
            .fold(f64::NEG_INFINITY, f64::max);
        self.evidence_gain > crate::diagnose::select::MIN_EVIDENCE_GAIN
            && self.evidence_gain > best + crate::diagnose::alternatives::PLAUSIBLE_MARGIN
    }

    /// The words of a step the data prefer: when, how large on each axis, the evidence.
    pub fn reason(&self) -> String {
        let (axis, z) = self.main_axis();
        format!(
            "a gyro drift step explains the misfit (drift-step, evidence gain {:.1} after the look-elsewhere penalty of {} times tried): \
             at t = {:.2} h, largest on axis {} ({z:.0}σ); step per axis {} deg/h — not repaired: split the run at that time, or exclude it and identify each part",
            self.evidence_gain,
            self.times_tried,
            self.t0_h,
            ["X", "Y", "Z"][axis],
            self.sizes()
        )
    }
}
