//! `driftid plan [RUN.csv …]`: the initial orientation of the next run (or, with no runs, of a
//! first pair) that most shrinks the weakest combination's total 1σ (the set-up's priors
//! included, as `identify` reports it) or best separates two effects.

use std::path::PathBuf;

use serde_json::json;

use super::common::{build_model, trusted_or, ModelArgs};
use super::joint::{fit_jointly, load_runs, run_consistency, runs_untrusted, LoadedRun, RunAlone};
use crate::catalog::Catalog;
use crate::format::sci;
use crate::identify::joint::RunSetup;
use crate::identify::Prepared;
use crate::plan::{rank, Criterion, Design, SoFar};
use crate::simulate::Scenario;

/// Arguments of `driftid plan`.
#[derive(clap::Args, Debug)]
pub struct PlanArgs {
    /// Runs made so far (none: plan a first pair from the simulator's defaults).
    pub recordings: Vec<PathBuf>,
    /// Duration of the planned run(s), h (default: the runs' mean, or 60 h).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::hours)]
    pub hours: Option<f64>,
    /// Sample interval of the planned run(s), s (default: that of the last run, or 1 s).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::rate_s)]
    pub rate_s: Option<f64>,
    /// Two effects to separate (minimise the canonical correlation of their estimates), e.g.
    /// `acc-bias,acc-scale`; both are added to the model if missing.
    #[arg(long, value_delimiter = ',')]
    pub separate: Option<Vec<String>>,
    /// Number of alternatives to list after the best.
    #[arg(long, default_value_t = 4, allow_hyphen_values = true, value_parser = super::args::alternatives)]
    pub alternatives: usize,
    /// Print one JSON object instead of the text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub model: ModelArgs,
}

/// Runs `driftid plan`.
pub fn run(args: &PlanArgs) -> anyhow::Result<()> {
    // --effects FILE: the user's effects join the catalog of this run.
    let catalog = super::common::catalog(&args.model)?;
    let result = run_with(args, &catalog);
    super::common::unless_numeric_failure(&catalog, result)
}

/// `driftid plan` with the run's `catalog`.
fn run_with(args: &PlanArgs, catalog: &Catalog) -> anyhow::Result<()> {
    let cfg = args.model.config()?;
    let effects = catalog.model_effects(&effects_named(args)?)?;
    let runs = load_runs(catalog, &args.recordings, args.model.latitude_deg, &cfg)?;
    let start = if runs.is_empty() {
        Start::defaults(args, &effects, &cfg)?
    } else {
        Start::after_runs(args, catalog, runs, &effects, &cfg)?
    };
    let Start {
        site,
        template,
        before,
        params,
        reasons,
    } = start;
    let model = build_model(site, &effects, &cfg)?;
    let criterion = match &args.separate {
        Some(p) => Criterion::separate(&model, &p[0], &p[1])?,
        None => Criterion::Weakest,
    };
    let spin = crate::progress::spinner(
        "evaluating the Fisher information and the set-up's share over 48 orientations",
    );
    let ranked = rank(
        &model,
        &effects,
        &criterion,
        before.as_ref(),
        &template,
        &params,
        &cfg,
    );
    spin.finish_and_clear();
    let ranked = ranked?;
    if ranked.is_empty() {
        anyhow::bail!("no candidate orientation could be evaluated");
    }
    let before_total = before.as_ref().map(|b| b.total_cov.clone());
    let before_score = before_total.as_ref().map(|c| criterion.score(&model, c));
    let before_noise_score = before
        .as_ref()
        .map(|b| criterion.score(&model, &b.estimate.cov));
    let names: Vec<&str> = (3..model.dim()).map(|i| model.param(i).name).collect();
    let units: Vec<&str> = (3..model.dim()).map(|i| model.param(i).unit).collect();
    let what = match &criterion {
        Criterion::Weakest => "largest total 1σ of a weak combination, deg/h".to_string(),
        Criterion::Separate { names, .. } => {
            format!("canonical correlation of {} and {}", names[0], names[1])
        }
    };
    let shown = Shown {
        names: &names,
        units: &units,
        what: &what,
        on_total: criterion.on_total(),
        before: before_total.as_ref(),
        before_noise: before.as_ref().map(|b| &b.estimate.cov),
        before_score,
        before_noise_score,
        ranked: &ranked,
        alternatives: args.alternatives,
    };
    if args.json {
        print_plan_json(&shown, &args.recordings, &reasons)?;
    } else {
        print_plan(&shown);
    }
    trusted_or(reasons)
}

/// The model's effects: `--with`, plus the two of `--separate` (checked: two different ones).
fn effects_named(args: &PlanArgs) -> anyhow::Result<Vec<String>> {
    let mut with = args.model.with.clone();
    if let Some(pair) = &args.separate {
        if pair.len() != 2 || pair[0] == pair[1] {
            anyhow::bail!(
                "--separate takes two different effects, e.g. acc-bias,acc-scale; got {pair:?}"
            );
        }
        for name in pair {
            if name != "paper" && !with.contains(name) {
                with.push(name.clone());
            }
        }
    }
    Ok(with)
}

/// Where a plan starts: the site, the planned run's template, the estimate of the runs so far
/// (none for a first pair), the parameters at which the information is evaluated, and why the
/// runs so far do not support a trusted plan (their faults, a misfit: exit 3).
struct Start {
    site: estimator_core::Site,
    template: Design,
    before: Option<SoFar>,
    params: Vec<f64>,
    reasons: Vec<String>,
}

impl Start {
    /// No runs yet: the simulator's defaults (the paper's coefficients, its latitude, length
    /// and rate unless given).
    fn defaults(
        args: &PlanArgs,
        effects: &[&dyn estimator_core::effects::Effect],
        cfg: &crate::identify::Config,
    ) -> anyhow::Result<Self> {
        let defaults = Scenario::paper();
        let lat = args.model.latitude_deg.unwrap_or(defaults.latitude_deg);
        let site = estimator_core::Site::new(lat, None);
        let rate_s = args.rate_s.unwrap_or(defaults.rate_s);
        // The simulator's raw noise: 1e-5 g per 60-s mean (was taken as the raw samples' 1σ,
        // √(60/rate) too small: the noise bound of a 24-h run at 10 s came out 2–14 % low).
        let sigma = cfg
            .raw_sigma_mps2
            .unwrap_or([1e-5 * site.gravity_mps2 * (60.0 / rate_s).sqrt(); 3]);
        let template = Design {
            orientation_deg: [0.0; 3],
            hours: args.hours.unwrap_or(defaults.hours),
            rate_s,
            raw_sigma_mps2: sigma,
        };
        let model = build_model(site, effects, cfg)?;
        let mut params = vec![0.0; model.dim() - 3];
        params[..12].copy_from_slice(&defaults.coefficients);
        Ok(Start {
            site,
            template,
            before: None,
            params,
            reasons: vec![],
        })
    }

    /// After `runs`: their joint estimate, the last run's site, rate and noise, their mean
    /// length (unless given).
    fn after_runs(
        args: &PlanArgs,
        catalog: &Catalog,
        mut runs: Vec<LoadedRun>,
        effects: &[&dyn estimator_core::effects::Effect],
        cfg: &crate::identify::Config,
    ) -> anyhow::Result<Self> {
        // Each run's set-up settled where its data put it, and its share, as `identify`
        // marginalises them in the joint total 1σ.
        let settle_run = |prep: &crate::identify::Prepared, id| {
            let s = crate::identify::setup::settle(effects, prep.clone(), cfg, id, None)?;
            Ok(RunAlone {
                prep: s.prep,
                id: s.id,
                setup: RunSetup {
                    cov: s.unc.setup_cov,
                    shift: s.unc.drift_shift,
                },
                judged: None,
            })
        };
        let (joint, _, _) = fit_jointly(
            catalog,
            &mut runs,
            effects,
            cfg,
            "identifying the runs so far",
            &settle_run,
        )?;
        let checks: Vec<_> = joint
            .runs
            .iter()
            .zip(&runs)
            .map(|(fit, r)| run_consistency(fit, &r.prep))
            .collect();
        let reasons = runs_untrusted(&runs, &joint, &checks);
        let shares: Vec<_> = joint
            .runs
            .iter()
            .map(|fit| (fit.alone.best().cov.clone(), fit.setup.cov.clone()))
            .collect();
        let last = &runs[runs.len() - 1].prep;
        let mean_hours = runs
            .iter()
            .map(|r| r.prep.measurements.last().map_or(0.0, |m| m.t_s) / 3600.0)
            .sum::<f64>()
            / runs.len() as f64;
        let template = Design {
            orientation_deg: [0.0; 3],
            hours: args.hours.unwrap_or(mean_hours),
            rate_s: args.rate_s.unwrap_or_else(|| rate_of(last, cfg.period_s)),
            raw_sigma_mps2: last.noise.raw_sigma_mps2,
        };
        // The stated site: the settled latitude's digits would set the designed run's latitude
        // prior to its 1e-4° floor (a 1.4–2× too small predicted total, measured).
        let mut site = runs[runs.len() - 1].stated_site;
        site.chart = Default::default();
        let params = joint.estimate.value.clone();
        Ok(Start {
            site,
            template,
            before: Some(SoFar {
                estimate: crate::identify::Estimate {
                    value: joint.estimate.value,
                    cov: joint.noise_cov,
                },
                total_cov: joint.estimate.cov,
                runs: shares,
            }),
            params,
            reasons,
        })
    }
}

/// What a plan shows: the parameters' names and units, the criterion's words, the total and the
/// noise-only covariance so far and their scores, the ranked candidates (best first) and
/// how many alternatives to list.
struct Shown<'a> {
    names: &'a [&'a str],
    units: &'a [&'a str],
    what: &'a str,
    on_total: bool,
    before: Option<&'a nalgebra::DMatrix<f64>>,
    before_noise: Option<&'a nalgebra::DMatrix<f64>>,
    before_score: Option<f64>,
    before_noise_score: Option<f64>,
    ranked: &'a [crate::plan::Candidate],
    alternatives: usize,
}

/// The plan as one JSON object (`--json`).
fn print_plan_json(
    s: &Shown<'_>,
    recordings: &[PathBuf],
    reasons: &[String],
) -> anyhow::Result<()> {
    let best = &s.ranked[0];
    let sig =
        |e: &nalgebra::DMatrix<f64>| (0..e.nrows()).map(|k| e[(k, k)].sqrt()).collect::<Vec<_>>();
    let out = json!({
        "criterion": s.what,
        "ranked_by": if s.on_total { "total" } else { "noise_only" },
        "runs_so_far": recordings.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "recommended": best.designs,
        "score_before": s.before_score,
        "score_before_noise_only": s.before_noise_score,
        "score_after": best.score,
        "score_after_noise_only": best.noise_score,
        "parameters": s.names,
        "units": s.units,
        "sigma_before": s.before_noise.map(sig),
        "sigma_total_before": s.before.map(sig),
        "sigma_total_after": sig(&best.total_cov),
        "sigma_after": sig(&best.cov),
        "alternatives": s.ranked.iter().skip(1).take(s.alternatives)
            .map(|c| json!({ "designs": c.designs, "score": c.score, "score_noise_only": c.noise_score }))
            .collect::<Vec<_>>(),
        "trusted": reasons.is_empty(),
        "untrusted_reasons": reasons,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

/// Mean sample interval of a prepared run, s (from the samples per filter period).
fn rate_of(prep: &Prepared, period_s: f64) -> f64 {
    period_s / crate::quality::steps::typical_count(&prep.measurements)
}

/// The plan as text: the recommendation, ready `driftid simulate` lines, the criterion before
/// and after, each parameter's 1σ now and after, and the alternatives.
fn print_plan(s: &Shown<'_>) {
    let best = &s.ranked[0];
    print_recommendation(best, s.before.is_some());
    let show = |v: f64| {
        if s.what.starts_with("canonical") {
            format!("{v:.3}")
        } else {
            sci(v)
        }
    };
    // The score ranked by first, the other in parentheses.
    let (first, other, other_name) = if s.on_total {
        (
            (s.before_score, best.score),
            (s.before_noise_score, best.noise_score),
            "noise only",
        )
    } else {
        (
            (s.before_noise_score, best.noise_score),
            (s.before_score, best.score),
            "total",
        )
    };
    let now = |v: Option<f64>| v.map_or(String::new(), |b| format!("{} now, ", show(b)));
    let (after, other_after) = if first.0.is_some() {
        ("after", " after")
    } else {
        ("after the pair", "")
    };
    println!(
        "{}: {}{} {after} ({other_name}: {}{}{other_after})",
        s.what,
        now(first.0),
        show(first.1),
        now(other.0),
        show(other.1)
    );
    if s.on_total {
        println!(
            "  ranked by the total 1σ: the noise bound plus each run's set-up priors (latitude, clock rate, gravity, \
             the vertical's daily tilt, the daily drift), as identify reports it"
        );
    } else {
        println!(
            "  ranked by the noise-only correlation (the information's): the set-up's common shifts correlate the \
             estimates on the total whatever the orientation"
        );
    }
    print_sigmas(s.names, s.units, s.before, best);
    if s.alternatives > 0 {
        println!("alternatives ({}):", s.what);
        for c in s.ranked.iter().skip(1).take(s.alternatives) {
            let key = if s.on_total { c.score } else { c.noise_score };
            println!("  {} → {}", orientations(c), show(key));
        }
    }
}

/// A candidate's start orientations, e.g. "(0, 90, 0) deg and (90, 0, 0) deg".
fn orientations(c: &crate::plan::Candidate) -> String {
    c.designs
        .iter()
        .map(|d| {
            format!(
                "({:.0}, {:.0}, {:.0}) deg",
                d.orientation_deg[0], d.orientation_deg[1], d.orientation_deg[2]
            )
        })
        .collect::<Vec<_>>()
        .join(" and ")
}

/// The recommended run(s) (`after_runs`: after the runs so far, else from the simulator's
/// defaults) and, per run, the `driftid simulate` line that makes it.
fn print_recommendation(best: &crate::plan::Candidate, after_runs: bool) {
    let d = &best.designs[0];
    println!(
        "plan: {} {}: initial orientation tx, ty, tz = {} ({:.1} h at {} s per sample)",
        if best.designs.len() == 2 {
            "first pair of runs"
        } else {
            "next run"
        },
        if after_runs {
            "after the runs so far"
        } else {
            "from the simulator's defaults"
        },
        orientations(best),
        d.hours,
        d.rate_s
    );
    for (k, d) in best.designs.iter().enumerate() {
        let o = d.orientation_deg;
        println!(
            "  to try it in simulation: driftid simulate --initial-orientation-deg {:.0},{:.0},{:.0} --hours {} --rate-s {} --out next{}.csv",
            o[0],
            o[1],
            o[2],
            d.hours,
            d.rate_s,
            if best.designs.len() > 1 { format!("-{}", k + 1) } else { String::new() }
        );
    }
}

/// Each parameter's total 1σ now (when there are runs so far), its total and noise-only 1σ
/// after the recommended run(s), and the ratio of the totals.
fn print_sigmas(
    names: &[&str],
    units: &[&str],
    before: Option<&nalgebra::DMatrix<f64>>,
    best: &crate::plan::Candidate,
) {
    println!(
        "{:<6} {:<16} {:>12} {:>12} {:>12} {:>8}",
        "coef", "unit", "total 1σ now", "total after", "noise after", "ratio"
    );
    for k in 0..names.len() {
        let after = best.total_cov[(k, k)].sqrt();
        let noise = best.cov[(k, k)].sqrt();
        let (now, ratio) = match before {
            Some(b) => {
                let now = b[(k, k)].sqrt();
                (sci(now), format!("{:>8.2}", now / after))
            }
            None => ("—".to_string(), String::new()),
        };
        println!(
            "{:<6} {:<16} {:>12} {:>12} {:>12} {}",
            names[k],
            units[k],
            now,
            sci(after),
            sci(noise),
            ratio
        );
    }
}
