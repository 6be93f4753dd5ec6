//! `driftid identify A.csv B.csv …`: one set of coefficients from several runs of one system.

use std::path::PathBuf;

use serde_json::{json, Map, Value};

use super::common::{build_model, load, print_findings, trusted_or, ModelArgs};
use super::diagnose::{diagnose_one, DiagnoseArgs};
use super::identify::IdentifyArgs;
use crate::catalog::Catalog;
use crate::consistency::{run_agreement, Consistency};
use crate::format::{sci, with_sigma};
use crate::identify::joint::{
    fit_alone, identify_joint_from, joint_bound, JointIdentification, Run, RunFit, RunSetup,
};
use crate::identify::{Config, Prepared};
use crate::simulate::read_truth;
use anyhow::Context as _;
use rayon::prelude::*;

/// One run as loaded and prepared.
pub(crate) struct LoadedRun {
    /// Where it came from.
    pub path: PathBuf,
    /// Its prepared measurements (site and chart its own); after [`fit_jointly`], at the run's
    /// settled set-up.
    pub prep: Prepared,
    /// The site as the recording states it (the settled latitude's digits are no statement of
    /// its precision).
    pub stated_site: estimator_core::Site,
    /// Stated initial orientation (ENU Euler angles), rad.
    pub orientation_rad: [f64; 3],
    /// The recording's free-text description, if any.
    pub description: Option<String>,
}

/// Refuses the same data given twice (issue 28): counted twice, it would narrow every 1σ by
/// √2 as if there were two runs. `seen` holds the runs checked so far with their samples'
/// fingerprints ([`super::common::Loaded::fingerprint`]); `path` is the next one. The same file
/// under any name (hard or symbolic link, another spelling) is caught without reading it
/// (`fingerprint` `None`); a copy, or the same samples in another file, by the fingerprint.
pub(crate) fn refuse_same_data(
    seen: &[(&std::path::Path, u64)],
    path: &std::path::Path,
    fingerprint: Option<u64>,
) -> anyhow::Result<()> {
    for (p, f) in seen {
        let why = if crate::output::same_file(p, path) {
            "is the same file as"
        } else if fingerprint == Some(*f) {
            "holds the same samples as"
        } else {
            continue;
        };
        anyhow::bail!(
            "{} {why} {}: the same data twice would be counted as two runs (a 1σ too narrow by √2); give each run once",
            path.display(),
            p.display()
        );
    }
    Ok(())
}

/// Loads and prepares every recording; an unreadable or refused one names its file, and so does
/// one that repeats another's data ([`refuse_same_data`]), before it is prepared.
pub(crate) fn load_runs(
    catalog: &Catalog,
    paths: &[PathBuf],
    latitude_deg: Option<f64>,
    cfg: &Config,
) -> anyhow::Result<Vec<LoadedRun>> {
    for (i, path) in paths.iter().enumerate() {
        let before: Vec<(&std::path::Path, u64)> =
            paths[..i].iter().map(|p| (p.as_path(), 0)).collect();
        refuse_same_data(&before, path, None)?;
    }
    let mut seen: Vec<(&std::path::Path, u64)> = Vec::new();
    paths
        .iter()
        .map(|path| {
            let loaded = load(catalog, path, latitude_deg)?;
            refuse_same_data(&seen, path, Some(loaded.fingerprint))?;
            seen.push((path.as_path(), loaded.fingerprint));
            let prep = super::common::prepare_loaded(path, &loaded, cfg)?;
            Ok(LoadedRun {
                path: path.clone(),
                stated_site: prep.site,
                prep,
                orientation_rad: loaded.initial_orientation_rad,
                description: loaded.description,
            })
        })
        .collect()
}

/// Why a joint fit is not trusted, run by run (empty when it is): each run's data faults, its
/// own fit not converged, the joint model not explaining it (`checks`, [`run_consistency`]).
/// `identify` with several runs and `plan` both.
pub(crate) fn runs_untrusted(
    runs: &[LoadedRun],
    joint: &JointIdentification,
    checks: &[Consistency],
) -> Vec<String> {
    let mut reasons = vec![];
    for ((r, c), fit) in runs.iter().zip(checks).zip(&joint.runs) {
        let name = r.path.display();
        reasons.extend(
            r.prep
                .untrusted_reasons()
                .into_iter()
                .map(|m| format!("{name}: {m}")),
        );
        if let Some(why) = fit.alone.convergence.and_then(|c| c.untrusted_reason()) {
            reasons.push(format!("{name} alone: {why}"));
        }
        if !c.is_consistent() {
            reasons.push(format!(
                "{name}: the joint model does not explain this run: {}; run `driftid diagnose` on it",
                c.failures.join("; "),
            ));
        }
        if let Some(why) = run_agreement(fit, &joint.estimate).failure() {
            reasons.push(format!(
                "{name}: {why}: were the runs made on one system, unchanged between them?"
            ));
        }
    }
    reasons
}

/// Whether the model explains one run (the one definition in [`crate::consistency`]): the run's
/// own fit at its settled set-up (whether its coefficients agree with the other runs' is
/// [`run_agreement`]).
pub(crate) fn run_consistency(fit: &RunFit, prep: &Prepared) -> Consistency {
    super::identify::fit_consistency(fit.innovations(), fit.residual_rms_mps2(prep), prep)
}

/// Runs the joint `driftid identify`.
pub(crate) fn run(args: &IdentifyArgs, catalog: &Catalog) -> anyhow::Result<()> {
    let (out, reasons) = identify_runs(
        catalog,
        &args.recordings,
        &args.model,
        &args.model.with,
        args.truth.as_deref(),
        args.json,
    )?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    }
    trusted_or(reasons)
}

/// The same data twice is refused before any run is diagnosed ([`refuse_same_data`]; reading is
/// quick next to a diagnosis; each run is read again by its diagnosis).
fn refuse_repeated_recordings(args: &DiagnoseArgs, catalog: &Catalog) -> anyhow::Result<()> {
    let mut seen: Vec<(&std::path::Path, u64)> = Vec::new();
    for (i, path) in args.recordings.iter().enumerate() {
        let before: Vec<(&std::path::Path, u64)> = args.recordings[..i]
            .iter()
            .map(|p| (p.as_path(), 0))
            .collect();
        refuse_same_data(&before, path, None)?;
    }
    for path in &args.recordings {
        let fingerprint =
            super::common::load_quietly(catalog, path, args.model.latitude_deg)?.fingerprint;
        refuse_same_data(&seen, path, Some(fingerprint))?;
        seen.push((path.as_path(), fingerprint));
    }
    Ok(())
}

/// `driftid diagnose A.csv B.csv …`: each run diagnosed (its own ladder), then the effects the
/// ladders chose, together, identified jointly from all runs. Effects with Gauss–Markov states
/// are per run and stay out of the joint model (said so).
pub(crate) fn diagnose(args: &DiagnoseArgs, catalog: &Catalog) -> anyhow::Result<()> {
    refuse_repeated_recordings(args, catalog)?;
    let mut per_run = vec![];
    let mut reasons = vec![];
    let mut with: Vec<String> = args.model.with.clone();
    for (i, path) in args.recordings.iter().enumerate() {
        if !args.json {
            println!("== run {}: {} ==", i + 1, path.display());
        }
        let dir = args
            .export
            .as_ref()
            .map(|d| d.join(format!("run{}", i + 1)));
        let one = diagnose_one(catalog, path, args, dir.as_deref())?;
        reasons.extend(
            one.reasons
                .iter()
                .map(|r| format!("{}: {r}", path.display())),
        );
        for e in &one.final_model {
            if !with.contains(e) {
                with.push(e.clone());
            }
        }
        per_run.push(one.json);
    }
    let (shared, per_run_only): (Vec<String>, Vec<String>) = with.into_iter().partition(|e| {
        catalog
            .by_name(e)
            .is_none_or(|x| (0..x.params().len()).all(|k| x.markov(k).is_none()))
    });
    if !args.json {
        println!(
            "== joint: paper{} from {} runs ==",
            shared.iter().map(|e| format!(" + {e}")).collect::<String>(),
            args.recordings.len()
        );
        if !per_run_only.is_empty() {
            println!(
                "(not shared between runs: {} — Gauss–Markov states vary within each run)",
                per_run_only.join(", ")
            );
        }
    }
    let (joint, joint_reasons) = identify_runs(
        catalog,
        &args.recordings,
        &args.model,
        &shared,
        None,
        args.json,
    )?;
    reasons.extend(joint_reasons);
    if args.json {
        let out = json!({
            "runs": per_run,
            "joint_model": shared,
            "not_shared": per_run_only,
            "joint": joint,
            "trusted": reasons.is_empty(),
            "untrusted_reasons": reasons,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    }
    trusted_or(reasons)
}

/// One run's own fit, assessed as a single run is ([`crate::assess`] for `identify`, the
/// set-up settled for `plan`): what the joint fit starts from and marginalises.
pub(crate) struct RunAlone {
    /// The run's measurements at its set-up's posterior.
    pub prep: Prepared,
    /// The run's fit there.
    pub id: crate::identify::Identification,
    /// What the run's set-up leaves uncertain in that fit.
    pub setup: RunSetup,
    /// What the run's reasons not to trust are drawn from, judged again on the joint estimate's
    /// scale once it is made (`None`: nothing is weighed, as for `plan`).
    pub judged: Option<crate::assess::Judged>,
}

/// How a run's own fit is assessed before the joint fit (see [`RunAlone`]).
pub(crate) type AssessRun<'c> =
    dyn Fn(&Prepared, crate::identify::Identification) -> anyhow::Result<RunAlone> + Sync + 'c;

/// The runs identified jointly ([`crate::identify::joint`]): each first alone; a run whose
/// metadata latitude the data contradict is refused ([`refuse_wrong_latitudes`]); each run's
/// fit assessed (`assess_run`: its set-up settled where its data put it, and what the set-up
/// leaves uncertain), then every run's set-up marginalised in the joint fit. `runs[r].prep`
/// becomes the run's settled measurements. Returns the fit, each run's model (at its settled
/// site) and each run's own reasons not to trust it; `label` is what the spinner says.
pub(crate) fn fit_jointly<'m>(
    catalog: &Catalog,
    runs: &mut [LoadedRun],
    effects: &'m [&'m dyn estimator_core::effects::Effect],
    cfg: &crate::identify::Config,
    label: &str,
    assess_run: &AssessRun<'_>,
) -> anyhow::Result<(
    JointIdentification,
    Vec<estimator_core::model::Model<'m>>,
    Vec<Vec<String>>,
)> {
    let models_at = |runs: &[LoadedRun]| {
        runs.iter()
            .map(|r| build_model(r.prep.site, effects, cfg))
            .collect::<anyhow::Result<Vec<_>>>()
    };
    let models = models_at(runs)?;
    let spin = crate::progress::spinner(label);
    let alone = fit_alone(&as_runs(&models, runs), cfg);
    spin.finish_and_clear();
    refuse_wrong_latitudes(catalog, runs, &alone, effects, cfg)?;
    let spin = crate::progress::spinner("each run's set-up and alternatives");
    let assessed = alone
        .into_par_iter()
        .zip(runs.par_iter())
        .enumerate()
        .map(|(i, (id, r))| assess_run(&r.prep, id?).with_context(|| format!("run {}", i + 1)))
        .collect::<anyhow::Result<Vec<RunAlone>>>();
    spin.finish_and_clear();
    let mut fits = vec![];
    let mut setups = vec![];
    let mut judged = vec![];
    for (r, a) in runs.iter_mut().zip(assessed?) {
        r.prep = a.prep;
        fits.push(Ok(a.id));
        setups.push(a.setup);
        judged.push(a.judged);
    }
    let models = models_at(runs)?;
    let spin = crate::progress::spinner(label);
    let joint = identify_joint_from(&as_runs(&models, runs), fits, &setups);
    spin.finish_and_clear();
    let joint = joint?;
    let reasons = alone_reasons(&joint, &judged);
    Ok((joint, models, reasons))
}

/// Each run's own reasons not to trust, its alternatives' shifts carried into the joint
/// estimate and judged against the joint total 1σ ([`crate::assess::Scale`]): a misstated clock
/// that would move one run's coefficient by 5σ of that run's total may move the joint estimate,
/// which the other runs pin, by less than its 1σ.
fn alone_reasons(
    joint: &JointIdentification,
    judged: &[Option<crate::assess::Judged>],
) -> Vec<Vec<String>> {
    let total: Vec<f64> = (0..joint.params.len())
        .map(|k| joint.estimate.sigma(k))
        .collect();
    joint
        .runs
        .iter()
        .zip(judged)
        .map(|(fit, j)| {
            let Some(j) = j else { return vec![] };
            let weight = fit.weight(&joint.estimate);
            let scale = crate::assess::Scale {
                weight: Some(&weight),
                total_sigma: &total,
            };
            j.reasons(&fit.alone, &scale)
        })
        .collect()
}

/// The runs as the joint fit takes them: each with its model.
fn as_runs<'a, 'm>(
    models: &'a [estimator_core::model::Model<'m>],
    runs: &'a [LoadedRun],
) -> Vec<Run<'a, 'm>> {
    models
        .iter()
        .zip(runs)
        .map(|(model, r)| Run {
            model,
            prep: &r.prep,
        })
        .collect()
}

/// A run its own model does not fit (`alone`, [`fit_alone`]) is first asked whether its metadata
/// latitude is the culprit ([`super::common::name_a_wrong_latitude`]). A run whose site is wrong
/// cannot join the others: refused, naming each such file and the data's latitude.
fn refuse_wrong_latitudes(
    catalog: &Catalog,
    runs: &mut [LoadedRun],
    alone: &[anyhow::Result<crate::identify::Identification>],
    effects: &[&dyn estimator_core::effects::Effect],
    cfg: &crate::identify::Config,
) -> anyhow::Result<()> {
    let mut named = vec![];
    for (r, id) in runs.iter_mut().zip(alone) {
        let misfit = id.as_ref().ok().filter(|id| {
            super::identify::consistency_of(id, &r.prep).is_some_and(|c| !c.is_consistent())
        });
        if let Some(id) = misfit {
            let spin = crate::progress::spinner("the model does not fit");
            let progress = crate::progress::follow(&spin);
            let rivals =
                |p: &_| super::common::latitude_rivals(p, catalog, effects, cfg, id, &progress);
            let fitted = (effects, id);
            let found =
                super::common::name_a_wrong_latitude(&r.prep, fitted, cfg, rivals, &progress);
            r.prep.findings.extend(found);
            spin.finish_and_clear();
        }
        named.extend(
            r.prep
                .findings
                .iter()
                .filter(|f| f.kind == crate::quality::Kind::Latitude)
                .map(|f| format!("{}: {}", r.path.display(), f.message)),
        );
    }
    if !named.is_empty() {
        anyhow::bail!(
            "{}; the runs are fitted together only when every run's site is right (`--latitude-deg` sets it for every run; a run made elsewhere needs its own `# latitude_deg:` corrected)",
            named.join("; ")
        );
    }
    Ok(())
}

/// A joint fit as `identify` makes it, ready to print or show: the runs, the fit, its bound,
/// each run's consistency under it, the truth and the reasons not to trust it.
pub(crate) struct JointFit {
    /// The runs as loaded and prepared.
    pub runs: Vec<LoadedRun>,
    /// The joint identification.
    pub joint: JointIdentification,
    /// The joint Cramér–Rao bound (1σ per parameter; NaN when it could not be computed).
    pub bound: Vec<f64>,
    /// The 1σ with every run's set-up marginalised (the joint estimate's).
    pub total_sigma: Vec<f64>,
    /// The 1σ with every run's set-up exactly known: noise only ("fit 1σ").
    pub noise_sigma: Vec<f64>,
    /// Each run's consistency under the joint estimate ([`run_consistency`]).
    pub checks: Vec<Consistency>,
    /// The true parameters (from `--truth`), in the joint fit's order.
    pub truth: Option<Vec<f64>>,
    /// Why the result is not trusted (empty: trusted).
    pub reasons: Vec<String>,
}

/// Identifies `paths` jointly with the paper's model plus `with`: each run's own fit assessed
/// as `identify` assesses one run ([`crate::assess`]: the set-up against its priors, the
/// alternatives on one evidence scale), the joint fit with every run's set-up marginalised, the
/// bound, each run's consistency under it. A run whose set-up the data contradict, or that
/// prefers an effect the joint model lacks, makes the joint result untrusted too.
pub(crate) fn fit_runs(
    catalog: &Catalog,
    paths: &[PathBuf],
    model_args: &ModelArgs,
    with: &[String],
    truth_path: Option<&std::path::Path>,
) -> anyhow::Result<JointFit> {
    let cfg = model_args.config()?;
    let effects = catalog.model_effects(with)?;
    let mut runs = load_runs(catalog, paths, model_args.latitude_deg, &cfg)?;
    let label = format!("identifying {} runs jointly", runs.len());
    let assess_run = |prep: &Prepared, id| {
        let a = crate::assess::assess(catalog, &effects, prep.clone(), &cfg, id)?;
        Ok(RunAlone {
            prep: a.prep,
            id: a.id,
            setup: RunSetup {
                cov: a.unc.setup_cov.clone(),
                shift: a.unc.drift_shift.clone(),
            },
            judged: Some(crate::assess::Judged {
                alternatives: a.alternatives,
                unc: a.unc,
                moved: a.moved,
                priors: a.cfg.setup,
            }),
        })
    };
    let (joint, models, alone_reasons) =
        fit_jointly(catalog, &mut runs, &effects, &cfg, &label, &assess_run)?;
    let joint_runs = as_runs(&models, &runs);
    let truth: Option<Vec<f64>> = match truth_path {
        Some(p) => Some(super::identify::truth_of(&read_truth(p)?, &joint.params)),
        None => None,
    };
    // At the truth where it is known (NaN: unknown), else at the estimate.
    let bound_at: Vec<f64> = (0..joint.params.len())
        .map(|k| {
            truth
                .as_ref()
                .map(|t| t[k])
                .filter(|v| v.is_finite())
                .unwrap_or(joint.estimate.value[k])
        })
        .collect();
    let bound = joint_bound(&joint_runs, &bound_at).unwrap_or_else(|e| {
        eprintln!("driftid: warning: no Cramér–Rao bound: {e:#}");
        vec![f64::NAN; bound_at.len()]
    });
    drop(joint_runs);
    let checks: Vec<Consistency> = joint
        .runs
        .iter()
        .zip(&runs)
        .map(|(fit, r)| run_consistency(fit, &r.prep))
        .collect();
    let mut reasons = runs_untrusted(&runs, &joint, &checks);
    for (r, alone) in runs.iter().zip(alone_reasons) {
        let name = r.path.display();
        reasons.extend(alone.into_iter().map(|m| format!("{name} alone: {m}")));
    }
    let n = joint.params.len();
    Ok(JointFit {
        total_sigma: (0..n).map(|k| joint.estimate.sigma(k)).collect(),
        noise_sigma: (0..n).map(|k| joint.noise_cov[(k, k)].sqrt()).collect(),
        runs,
        joint,
        bound,
        checks,
        truth,
        reasons,
    })
}

/// Identifies `paths` jointly with the paper's model plus `with` ([`fit_runs`]); prints the text
/// unless `json` and returns the JSON object and the reasons not to trust it.
pub(crate) fn identify_runs(
    catalog: &Catalog,
    paths: &[PathBuf],
    model_args: &ModelArgs,
    with: &[String],
    truth_path: Option<&std::path::Path>,
    as_json: bool,
) -> anyhow::Result<(Value, Vec<String>)> {
    let fit = fit_runs(catalog, paths, model_args, with, truth_path)?;
    let reasons = fit.reasons.clone();
    let mut out = to_json(&fit);
    out["trusted"] = json!(reasons.is_empty());
    out["untrusted_reasons"] = json!(reasons);
    if !as_json {
        print_text(&fit);
        if !reasons.is_empty() {
            println!(
                "NOT TRUSTED: the numbers above are computed but the tool does not trust them:"
            );
            for r in &reasons {
                println!("  - {r}");
            }
        }
    }
    Ok((out, reasons))
}

/// The weakest combination of one axis in words (`identify`'s line and the report's).
pub(crate) fn weak_line(w: &crate::identify::WeakCombination) -> String {
    format!(
        "axis {}: weakest combination {:.2}·D0 {:+.2}·g·Dx {:+.2}·g·Dy {:+.2}·g·Dz, 1σ {} deg/h, {:.1}x weaker than the next{}",
        w.axis,
        w.direction[0],
        w.direction[1],
        w.direction[2],
        w.direction[3],
        sci(w.sigma_degph),
        w.ratio_to_next,
        if w.ratio_to_next >= 10.0 {
            " — the runs do not separate it: `driftid plan` recommends the next orientation"
        } else {
            ""
        }
    )
}

/// Initial orientation in degrees, rounded to 1e-4 deg.
pub(crate) fn deg3(a: &[f64; 3]) -> [f64; 3] {
    a.map(|v| (v.to_degrees() * 1e4).round() / 1e4)
}

fn print_text(fit: &JointFit) {
    let JointFit {
        runs,
        joint,
        bound,
        total_sigma: total,
        noise_sigma: noise,
        checks,
        truth,
        ..
    } = fit;
    let truth = truth.as_deref();
    print_runs(joint, runs, checks);
    println!(
        "joint drift coefficients from {} runs (each run's smoother relinearised about the joint estimate)",
        runs.len()
    );
    // The name column as wide as the longest name (`GXxx-zz`), 6 at least.
    let w = joint
        .params
        .iter()
        .map(|p| p.name.chars().count())
        .fold(6, usize::max);
    print!(
        "{:<w$} {:<16} {:>12} {:>10} {:>10} {:>10} {:>12}",
        "coef", "unit", "estimate", "1σ total", "fit 1σ", "CRB 1σ", "best run 1σ"
    );
    if truth.is_some() {
        print!(" {:>10} {:>10} {:>7}", "truth", "error", "err/σ");
    }
    println!();
    let e = &joint.estimate;
    for (k, p) in joint.params.iter().enumerate() {
        let alone = joint
            .runs
            .iter()
            .map(|f| f.alone.best().sigma(k))
            .fold(f64::INFINITY, f64::min);
        print!(
            "{:<w$} {:<16} {:>12} {:>10} {:>10} {:>10} {:>12}",
            p.name,
            p.unit,
            with_sigma(e.value[k], total[k]),
            sci(total[k]),
            sci(noise[k]),
            sci(bound[k]),
            sci(alone)
        );
        // A truth the simulator cannot know (NaN) leaves its columns blank.
        if let Some(t) = truth.filter(|t| t[k].is_finite()) {
            let err = e.value[k] - t[k];
            print!(" {:>10} {:>10} {:>7.2}", t[k], sci(err), err / total[k]);
        }
        println!();
    }
    print_weak(&joint.weak);
}

/// Each run's line: findings, length, orientation, its own fit's residual over the floor and
/// NIS/3 and whether the model explains it ([`run_consistency`]), and whether its coefficients
/// agree with the joint ones ([`run_agreement`]).
fn print_runs(joint: &JointIdentification, runs: &[LoadedRun], checks: &[Consistency]) {
    for ((r, fit), c) in runs.iter().zip(&joint.runs).zip(checks) {
        print_findings(&r.prep.findings);
        let rms = c.rms_over_floor;
        let agree = run_agreement(fit, &joint.estimate);
        println!(
            "run {}: {:.2} h, {} updates, initial orientation {:?} deg ({:?} chart); residual/floor [{:.3}, {:.3}, {:.3}]; NIS/3 {:.3}; {}; against the joint χ² {:.1} for {} (p {:.1e})",
            r.path.display(),
            fit.alone.final_time_h,
            r.prep.measurements.len(),
            deg3(&r.orientation_rad),
            r.prep.site.chart,
            rms[0],
            rms[1],
            rms[2],
            c.nis_mean,
            if c.is_consistent() { "consistent" } else { "NOT consistent" },
            agree.chi2,
            agree.dof,
            agree.p_value
        );
    }
}

/// Each axis's weakest combination of drift coefficients ([`weak_line`]).
fn print_weak(weak: &[crate::identify::WeakCombination]) {
    for w in weak {
        println!("{}", weak_line(w));
    }
}

fn to_json(fit: &JointFit) -> Value {
    let joint = &fit.joint;
    let mut coefs = Map::new();
    let e = &joint.estimate;
    for (k, p) in joint.params.iter().enumerate() {
        let mut o = json!({ "value": e.value[k], "sigma_total": fit.total_sigma[k], "sigma": fit.noise_sigma[k], "bound": fit.bound[k], "unit": p.unit,
            "alone_sigma": joint.runs.iter().map(|f| f.alone.best().sigma(k)).collect::<Vec<_>>() });
        if let Some(t) = fit.truth.as_deref().filter(|t| t[k].is_finite()) {
            o["truth"] = json!(t[k]);
            o["error"] = json!(e.value[k] - t[k]);
        }
        coefs.insert(p.name.to_string(), o);
    }
    let run_objs: Vec<Value> = fit
        .runs
        .iter()
        .zip(&joint.runs)
        .zip(&fit.checks)
        .map(|((r, fit), c)| {
            json!({
                "recording": r.path.display().to_string(),
                "initial_orientation_deg": deg3(&r.orientation_rad),
                "chart": format!("{:?}", r.prep.site.chart),
                "final_time_h": fit.alone.final_time_h,
                "updates": r.prep.measurements.len(),
                "residual_rms_mps2": fit.residual_rms_mps2(&r.prep),
                "floor_mps2": r.prep.floor_mps2(),
                "nis_mean": c.nis_mean,
                "consistency": c,
                "agreement": run_agreement(fit, &joint.estimate),
                "data_quality": { "findings": r.prep.findings },
            })
        })
        .collect();
    json!({
        "runs": run_objs,
        "coefficients": coefs,
        "weak_combinations": joint.weak,
        "method": "joint Gauss-Newton: per-run iterated RTS smoothers, information fused",
    })
}
