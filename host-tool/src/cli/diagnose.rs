//! `driftid diagnose`: compare the model with the measurements, rank the missing effects, and
//! climb the model ladder.

use std::path::PathBuf;

use serde_json::json;

use anyhow::Context as _;

use super::common::{load, print_findings, trusted_or, ModelArgs};
use crate::catalog::Catalog;
use crate::diagnose::types::{model_name, model_name_compact};
use crate::diagnose::{ladder_from, DiagnoseConfig, Diagnosis, Ladder, Rung};
use crate::format::{p_value, pm, sci};

/// Arguments of `driftid diagnose`.
#[derive(clap::Args, Debug)]
pub struct DiagnoseArgs {
    /// Recording(s) (CSV). With several runs of one system each is diagnosed, then the effects
    /// their ladders chose are identified jointly from all of them.
    #[arg(required = true, num_args = 1..)]
    pub recordings: Vec<PathBuf>,
    /// Truth file of a simulated run (`NAME.truth.json`; one recording): adds error and error/σ
    /// columns to the final model's coefficients.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Print one JSON object instead of the text summary.
    #[arg(long)]
    pub json: bool,
    /// Only diagnose the given model; do not climb the ladder.
    #[arg(long)]
    pub no_ladder: bool,
    /// Write the residual time series of every rung as CSV into this folder (units in the
    /// headers; for MATLAB, pandas): rung0.csv, rung1.csv, … and rungs.csv.
    #[arg(long, value_name = "DIR")]
    pub export: Option<PathBuf>,
    /// Replace existing export files that are not files driftid wrote.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub model: ModelArgs,
}

/// Prints one diagnosis as text.
pub(crate) fn print_diagnosis(d: &Diagnosis) {
    println!("model: {}", model_name(&d.model));
    println!(
        "  residual RMS [{}, {}, {}] m/s^2 = [{:.3}, {:.3}, {:.3}] × noise floor [{}, {}, {}] m/s^2",
        sci(d.residual_rms_mps2[0]),
        sci(d.residual_rms_mps2[1]),
        sci(d.residual_rms_mps2[2]),
        d.residual_rms_over_floor[0],
        d.residual_rms_over_floor[1],
        d.residual_rms_over_floor[2],
        sci(d.floor_mps2[0]),
        sci(d.floor_mps2[1]),
        sci(d.floor_mps2[2])
    );
    println!(
        "  mean NIS/3 {:.3} (99.9 % band {:.3}–{:.3}); Ljung–Box Q {:.1} on {} dof, p = {}",
        d.nis_mean,
        d.consistency.nis_band[0],
        d.consistency.nis_band[1],
        d.whiteness.ljung_box_q,
        d.whiteness.dof,
        p_value(
            d.whiteness.p_value,
            crate::stats::chi2_ln_sf(d.whiteness.ljung_box_q, d.whiteness.dof)
        )
    );
    print_where_it_fails(d);
    print_ranking(&d.ranking);
    for cf in &d.confounding {
        if cf.separated {
            println!("  similar signatures: {} vs {} (canonical correlation {:.3}) — but the data prefer {} (−2 ln p lower by {:.1})", cf.a, cf.b, cf.canonical_correlation, cf.a, cf.statistic_gap);
        } else {
            println!("  NOT SEPARATED: {} vs {} (canonical correlation {:.3}, −2 ln p apart by only {:.1}); what would separate them: {}", cf.a, cf.b, cf.canonical_correlation, cf.statistic_gap, cf.separate_by);
        }
    }
    println!("  verdict: {}", d.verdict);
}

/// Where the fit fails (the first 8 windows of high NIS) and the regressors the residual
/// correlates with beyond the 99 % bound.
fn print_where_it_fails(d: &Diagnosis) {
    if !d.failures.is_empty() {
        let w: Vec<String> = d
            .failures
            .iter()
            .take(8)
            .map(|f| {
                format!(
                    "{:.1}–{:.1} h (NIS/3 {:.2}, axis {})",
                    f.start_h, f.end_h, f.nis_mean, f.worst_axis
                )
            })
            .collect();
        println!(
            "  where it fails: {}{}",
            w.join("; "),
            if d.failures.len() > 8 {
                format!(" … ({} windows)", d.failures.len())
            } else {
                String::new()
            }
        );
    }
    let strong: Vec<String> = d
        .correlations
        .iter()
        .filter(|c| c.corr.iter().any(|r| r.abs() > c.bound99))
        .map(|c| {
            format!(
                "{} [{:+.2}, {:+.2}, {:+.2}]",
                c.regressor, c.corr[0], c.corr[1], c.corr[2]
            )
        })
        .collect();
    if !strong.is_empty() {
        println!("  residual correlates with: {}", strong.join(", "));
    }
}

/// The candidates' table: score test, Holm-adjusted p, evidence and refit of each missing
/// effect, with its largest parameter.
fn print_ranking(ranking: &[crate::diagnose::Candidate]) {
    println!(
        "  {:<13} {:>10} {:>4} {:>11} {:>11}  {:>9} {:>21}  largest parameter (estimate ± 1σ; detectable from)",
        "candidate", "statistic", "dof", "p", "p (Holm)", "evidence", "refit RMS/floor"
    );
    for c in ranking {
        if let Some(why) = &c.untestable {
            println!("  {:<13} not tested: {why}", c.effect);
            continue;
        }
        let big = c.params.iter().max_by(|a, b| {
            (a.value / a.sigma)
                .abs()
                .total_cmp(&(b.value / b.sigma).abs())
        });
        let big = big
            .map(|p| {
                format!(
                    "{} = {} {} (≥ {})",
                    p.name,
                    pm(p.value, p.sigma),
                    p.unit,
                    sci(p.min_detectable)
                )
            })
            .unwrap_or_default();
        let (ev, after) = match &c.refit {
            // `≈`: a refit that did not converge, its evidence approximate and not ranked.
            Some(r) => (
                format!(
                    "{}{:+.1}",
                    if r.converged() { "" } else { "≈" },
                    r.evidence_gain
                ),
                format!(
                    "[{:.2}, {:.2}, {:.2}]",
                    r.rms_over_floor[0], r.rms_over_floor[1], r.rms_over_floor[2]
                ),
            ),
            None => ("—".into(), "(not refitted)".into()),
        };
        println!(
            "  {:<13} {:>10.1} {:>4} {:>11} {:>11}  {:>9} {:>21}  {big}",
            c.effect,
            c.statistic,
            c.dof,
            p_value(c.p_value, c.ln_p_value),
            p_value(c.p_adjusted, c.ln_p_adjusted),
            ev,
            after
        );
    }
    let unconverged: Vec<&str> = ranking
        .iter()
        .filter(|c| c.refit.as_ref().is_some_and(|r| !r.converged()))
        .map(|c| c.effect.as_str())
        .collect();
    if !unconverged.is_empty() {
        println!(
            "  ≈ refit did not converge ({}): its evidence is that of a trajectory still moving, approximate, and not ranked",
            unconverged.join(", ")
        );
    }
}

/// Prints the ladder.
pub(crate) fn print_ladder(rungs: &[Rung]) {
    println!("\nmodel ladder (watch the error fall):");
    println!(
        "  {:<40} {:>22} {:>9} {:>10}  added next",
        "model", "RMS/floor [x, y, z]", "NIS/3", "LB p"
    );
    for r in rungs {
        let m = model_name(&r.model);
        let next = r
            .next
            .as_ref()
            .map(|(e, p)| match p.is_nan() {
                // A drift step has no score test: its profile's evidence chose it.
                true => e.clone(),
                false => format!("{e} (p = {})", p_value(*p, f64::NAN)),
            })
            .unwrap_or_else(|| "—".into());
        println!(
            "  {:<40} [{:>5.3}, {:>5.3}, {:>5.3}] {:>9.3} {:>10}  {next}",
            m,
            r.residual_rms_over_floor[0],
            r.residual_rms_over_floor[1],
            r.residual_rms_over_floor[2],
            r.nis_mean,
            p_value(r.whiteness_p, f64::NAN)
        );
    }
    for r in rungs {
        if let Some(why) = &r.next_reason {
            println!("  why: {why}");
        }
    }
    if let Some(last) = rungs.last() {
        if !last.effect_params.is_empty() {
            println!("  added effects' parameters (last model):");
            // The value column does not shift with a long name (`GXxx-zz-long`).
            let nw = last
                .effect_params
                .iter()
                .map(|p| p.0.chars().count())
                .fold(8, usize::max);
            for (name, unit, v, s) in &last.effect_params {
                let resolved = if v.abs() < 2.0 * s {
                    "  (not resolved by this run: |value| < 2σ)"
                } else {
                    ""
                };
                println!("    {name:<nw$} {} {unit}{resolved}", pm(*v, *s));
            }
        }
    }
    if rungs.len() > 1 {
        let (a, b) = (&rungs[0], &rungs[rungs.len() - 1]);
        println!("  drift coefficients, first → last model (1σ of the last; how much the added effects widen it):");
        for ((name, v0, s0), (_, v1, s1)) in a.coefficients.iter().zip(&b.coefficients) {
            println!(
                "    {name:<4} {v0:>12.6} → {}  (moved {:+.1} σ; 1σ ×{:.1})",
                pm(*v1, *s1),
                (v1 - v0) / s1,
                s1 / s0
            );
        }
        let widest = a
            .coefficients
            .iter()
            .zip(&b.coefficients)
            .map(|((_, _, s0), (_, _, s1))| s1 / s0)
            .fold(0.0, f64::max);
        if widest > WIDENED_POINT_TO_PLAN {
            println!(
                "  the added effects widen a 1σ up to ×{widest:.0}: one static run cannot separate them from the drift; a second run from another orientation can — `driftid plan RUN.csv --with {}` says which",
                b.model.join(",")
            );
        }
    }
}

/// A 1σ widened more than this by the added effects earns a pointer to `driftid plan`.
const WIDENED_POINT_TO_PLAN: f64 = 3.0;

/// Runs `driftid diagnose`.
pub fn run(args: &DiagnoseArgs) -> anyhow::Result<()> {
    // --effects FILE: the user's effects join the catalog of this run.
    let catalog = super::common::catalog(&args.model)?;
    let result = run_with(args, &catalog);
    super::common::unless_numeric_failure(&catalog, result)
}

/// `driftid diagnose` with the run's `catalog`.
fn run_with(args: &DiagnoseArgs, catalog: &Catalog) -> anyhow::Result<()> {
    if args.truth.is_some() && args.recordings.len() > 1 {
        anyhow::bail!("--truth takes one recording (a truth file describes one simulated run)");
    }
    // The export's files are checked before the long computation (and again before writing).
    if let Some(dir) = &args.export {
        let rungs = if args.no_ladder { 1 } else { 4 };
        if args.recordings.len() > 1 {
            for i in 0..args.recordings.len() {
                check_export(&dir.join(format!("run{}", i + 1)), rungs, args)?;
            }
        } else {
            check_export(dir, rungs, args)?;
        }
    }
    if args.recordings.len() > 1 {
        return super::joint::diagnose(args, catalog);
    }
    let one = diagnose_one(catalog, &args.recordings[0], args, args.export.as_deref())?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&one.json)?);
    }
    trusted_or(one.reasons)
}

/// The outcome of one recording's diagnosis.
pub(crate) struct OneDiagnosis {
    /// The JSON object (`--json`).
    pub json: serde_json::Value,
    /// Reasons not to trust it (empty: trusted).
    pub reasons: Vec<String>,
    /// Effects of the ladder's final model (besides the paper's).
    pub final_model: Vec<String>,
}

/// Why a ladder's result is not trusted (empty when it is): the data's faults, a rung whose
/// choice the evidence did not settle ([`crate::diagnose::select::Choice::confounded`]), then
/// its final model's fit — not converged, or not explaining the measurements. `diagnose` and
/// `report` both.
pub(crate) fn ladder_untrusted(
    faults: &[String],
    diagnoses: &[Diagnosis],
    (recording, max_rungs): (&std::path::Path, usize),
) -> Vec<String> {
    let mut reasons = faults.to_vec();
    reasons.extend(stopped_at_the_cap(diagnoses, recording, max_rungs));
    reasons.extend(
        diagnoses
            .iter()
            .filter_map(|d| d.choice.as_ref()?.confounded.clone()),
    );
    reasons.extend(diagnoses.iter().filter_map(|d| d.unconverged_rival.clone()));
    if let Some(d) = diagnoses.last() {
        reasons.extend(d.convergence.and_then(|c| c.untrusted_reason()));
        if !d.consistency.is_consistent() {
            reasons.push(format!(
                "the final model does not explain the measurements: {}",
                d.consistency.failures.join("; ")
            ));
        }
    }
    reasons
}

/// Why a ladder of `recording` cut short by its cap (`max_rungs`, more than one rung) is not
/// trusted: its last model still misses an effect that earns its place; and how to go on from
/// there (the ladder started from the last model's effects, `--with`).
fn stopped_at_the_cap(
    diagnoses: &[Diagnosis],
    recording: &std::path::Path,
    max_rungs: usize,
) -> Option<String> {
    let (last, below) = diagnoses.split_last()?;
    let choice = last.choice.as_ref()?;
    if max_rungs < 2 || diagnoses.len() < max_rungs {
        return None;
    }
    let head = format!(
        "the model ladder stopped at its {max_rungs} models, the last still missing an effect: {}",
        choice.reason
    );
    // `--with` takes catalog effects; one made for this run (a drift step, a warm-up, a
    // periodic drift: profiled) the ladder makes again.
    let made: Vec<&str> = below
        .iter()
        .filter_map(|d| d.choice.as_ref().filter(|c| c.profiled.is_some()))
        .map(|c| c.effect.as_str())
        .collect();
    let with: Vec<&str> = last
        .model
        .iter()
        .map(String::as_str)
        .filter(|m| !made.contains(m))
        .collect();
    let run = recording.display();
    Some(match (with.is_empty(), made.is_empty()) {
        (true, _) => head,
        (false, true) => format!(
            "{head}; `driftid diagnose {run} --with {}` goes on from that model",
            with.join(",")
        ),
        (false, false) => format!(
            "{head}; `driftid diagnose {run} --with {}` goes on from its catalog effects (the ladder \
             makes {} for the run again)",
            with.join(","),
            made.join(", ")
        ),
    })
}

/// Diagnoses one recording: prints the text unless `--json`, returns the JSON and the reasons.
pub(crate) fn diagnose_one(
    catalog: &Catalog,
    recording: &std::path::Path,
    args: &DiagnoseArgs,
    export_dir: Option<&std::path::Path>,
) -> anyhow::Result<OneDiagnosis> {
    let mut cfg = DiagnoseConfig {
        identify: args.model.config()?,
        max_rungs: if args.no_ladder {
            1
        } else {
            crate::diagnose::DEFAULT_MAX_RUNGS
        },
        ..Default::default()
    };
    anyhow::ensure!(
        cfg.identify.smoother_iterations > 0,
        "diagnose needs the converged identification; drop --single-pass"
    );
    let c = climb(catalog, recording, &args.model, &mut cfg)?;
    let mut reasons = ladder_untrusted(&c.faults, &c.diagnoses, (recording, cfg.max_rungs));
    reasons.extend(c.assessed.reasons.iter().cloned());
    let truth = match &args.truth {
        Some(p) => Some(super::identify::truth_of(
            &crate::simulate::read_truth(p)?,
            &c.assessed.id.params,
        )),
        None => None,
    };
    let final_rows = super::identify::rows(
        &c.assessed.id,
        &c.assessed.unc,
        &c.assessed.alternatives,
        &super::common::build_model(c.assessed.prep.site, &c.final_effects, &cfg.identify)?,
        &c.assessed.prep,
        truth.as_deref(),
    );
    if let Some(dir) = export_dir {
        check_export(dir, c.diagnoses.len(), args)?;
        export(dir, &c.diagnoses, &final_rows)?;
    }
    let final_model = c
        .diagnoses
        .last()
        .map(|d| d.model.clone())
        .unwrap_or_default();
    let out = one_json(recording, &c, &final_rows, &reasons)?;
    if !args.json {
        print_one(recording, &c, cfg.identify.period_s, &final_rows, &reasons);
    }
    Ok(OneDiagnosis {
        json: out,
        reasons,
        final_model,
    })
}

/// One recording taken up the model ladder and assessed: the prepared run, the data's faults,
/// every rung's diagnosis, the final model's effects and its assessment (its honest 1σ and the
/// alternatives it cannot rule out).
pub(crate) struct Climbed<'c> {
    pub prep: crate::identify::Prepared,
    /// The recording's free-text description, if any.
    pub description: Option<String>,
    pub faults: Vec<String>,
    pub diagnoses: Vec<Diagnosis>,
    pub rungs: Vec<Rung>,
    pub final_effects: Vec<&'c dyn estimator_core::effects::Effect>,
    pub assessed: crate::assess::Assessment,
}

/// Loads and prepares `recording`, fits the starting model (`cfg.identify` takes what the
/// starting fit settles), climbs the ladder (one rung when the data have faults: a fault is
/// named as a fault, never explained by a physical effect) and assesses the final model by
/// the one path shared with identify and report. `diagnose` and `report` both climb so.
pub(crate) fn climb<'c>(
    catalog: &'c Catalog,
    recording: &std::path::Path,
    model: &super::common::ModelArgs,
    cfg: &mut DiagnoseConfig,
) -> anyhow::Result<Climbed<'c>> {
    let loaded = load(catalog, recording, model.latitude_deg)?;
    let effects = catalog.model_effects(&model.with)?;
    let mut prep = super::common::prepare_loaded(recording, &loaded, &cfg.identify)?;
    let mut stated = None;
    let mut at_start = crate::assess::AtTheStart::default();
    let mut known = None;
    let spin = crate::progress::spinner("fitting the starting model");
    let first = super::common::starting_fit(
        &mut prep,
        catalog,
        &effects,
        &mut cfg.identify,
        (&mut stated, &mut at_start),
        &mut known,
        &crate::progress::follow(&spin),
    )?;
    spin.finish_and_clear();
    let faults = prep.untrusted_reasons();
    if !faults.is_empty() {
        cfg.max_rungs = 1;
    }
    let spin = crate::progress::spinner("climbing the model ladder");
    cfg.progress = crate::progress::follow(&spin);
    let Ladder {
        diagnoses,
        rungs,
        identification,
        effects: final_effects,
    } = ladder_from(&prep, catalog, &effects, cfg, first)?;
    spin.finish_and_clear();
    let spin =
        crate::progress::spinner("the set-up's uncertainty and the alternative explanations");
    let (at, identification) = super::common::for_assessment(
        stated,
        &prep,
        &final_effects,
        &cfg.identify,
        identification,
    )?;
    let mut assessed = crate::assess::assess_with(
        catalog,
        &final_effects,
        at,
        &cfg.identify,
        identification,
        known.as_ref(),
        &crate::progress::follow(&spin),
    )?;
    let (added, ladder_gain) = crate::diagnose::ladder::additions(&diagnoses);
    let overruled = crate::diagnose::ladder::overruled(&diagnoses);
    assessed.weigh_instead_of_the_ladder(&at_start, (&added, ladder_gain), &overruled);
    spin.finish_and_clear();
    // A repair tunes the wander again where it puts the set-up.
    let final_effects = catalog.as_tuned(&final_effects, &assessed.id);
    Ok(Climbed {
        prep,
        description: loaded.description,
        faults,
        diagnoses,
        rungs,
        final_effects,
        assessed,
    })
}

/// The JSON object of one recording's diagnosis (`--json`): the starting model's diagnosis,
/// the ladder, the final model's verdict, coefficients, set-up uncertainty and alternatives.
fn one_json(
    recording: &std::path::Path,
    c: &Climbed,
    final_rows: &[super::identify::Row],
    reasons: &[String],
) -> anyhow::Result<serde_json::Value> {
    let (diagnoses, assessed) = (&c.diagnoses, &c.assessed);
    let d = &diagnoses[0];
    let mut out = json!({
        "recording": recording.display().to_string(),
        "model": d.model,
        "residual_rms_over_floor": d.residual_rms_over_floor,
        "residual_rms_mps2": d.residual_rms_mps2,
        "floor_mps2": d.floor_mps2,
        "nis_mean": d.nis_mean,
        "nis_band95": d.nis_band95,
        "whiteness_p": d.whiteness.p_value,
        "ljung_box": { "q": d.whiteness.ljung_box_q, "dof": d.whiteness.dof },
        "ranking": d.ranking,
        "confounding": d.confounding,
        "failures": d.failures,
        "verdict": d.verdict,
        "ladder": c.rungs,
        "final_verdict": diagnoses.last().map(|d| d.verdict.clone()),
        "final_consistency": diagnoses.last().map(|d| d.consistency.clone()),
        "data_quality": { "findings": assessed.prep.findings },
        "coefficients": super::identify::coefficients_json(final_rows),
        "setup_uncertainty": assessed.unc.contributions,
        "alternatives": assessed.alternatives,
        "trusted": reasons.is_empty(),
        "untrusted_reasons": reasons,
    });
    if let Some(gm) = &assessed.id.markov {
        out["drift_markov"] = serde_json::to_value(gm)?;
    }
    Ok(out)
}

/// One recording's diagnosis as text: findings, every rung's diagnosis, the ladder, the final
/// model's coefficients (filter period `period_s`), set-up and alternatives, and why it is not
/// trusted.
fn print_one(
    recording: &std::path::Path,
    c: &Climbed,
    period_s: f64,
    final_rows: &[super::identify::Row],
    reasons: &[String],
) {
    let assessed = &c.assessed;
    print_findings(&assessed.prep.findings);
    if !c.faults.is_empty() {
        println!("the data have faults the tool did not repair: they are named above as faults; no physical effect is added to explain them (no model ladder)");
    }
    println!(
        "{}: {} updates of {} s",
        recording.display(),
        c.prep.measurements.len(),
        period_s
    );
    print_diagnosis(&c.diagnoses[0]);
    if c.diagnoses.len() > 1 {
        for d in &c.diagnoses[1..] {
            println!();
            print_diagnosis(d);
        }
    }
    print_ladder(&c.rungs);
    println!();
    println!("final model's coefficients with the 1σ this run supports:");
    super::identify::print_table(final_rows, true);
    if let Some(gm) = &assessed.id.markov {
        println!("{}", gm.line());
    }
    super::identify::print_setup(&assessed.unc, &assessed.id);
    super::identify::print_alternatives(&assessed.alternatives, &assessed.unc, &assessed.id);
    if !reasons.is_empty() {
        println!("NOT TRUSTED:");
        for r in reasons {
            println!("  - {r}");
        }
    } else {
        super::identify::print_trusted_on(final_rows, &recording.display().to_string());
    }
}

/// The header of `rungs.csv`.
const INDEX_HEADER: &str =
    "rung,model,rms_over_floor_x,rms_over_floor_y,rms_over_floor_z,nis_mean,whiteness_p,consistent";

/// The header of `coefficients.csv`: the final model's parameters with the total 1σ (the
/// headline), the noise-only 1σ, the bound and the source that dominates the total.
const COEFFICIENTS_HEADER: &str = "name,unit,value,sigma_total,sigma_noise,crb,dominant";

/// The header of `rungK.csv`.
fn rung_header() -> String {
    let mut h = String::from("t_h");
    for q in [
        "measured",
        "predicted",
        "residual",
        "innovation",
        "innovation_sigma",
    ] {
        for a in ["x", "y", "z"] {
            h.push_str(&format!(",{q}_{a}_mps2"));
        }
    }
    h + ",whitened_x,whitened_y,whitened_z,nis"
}

/// Checks the files an export of `rungs` rungs writes into `dir` ([`crate::output::Outputs`]):
/// none is one of the command's inputs (recordings, effects files), and none replaces a file
/// driftid did not write there, unless `--force`.
pub(crate) fn check_export(
    dir: &std::path::Path,
    rungs: usize,
    args: &DiagnoseArgs,
) -> anyhow::Result<()> {
    let mut inputs: Vec<&std::path::Path> = args.recordings.iter().map(|p| p.as_path()).collect();
    inputs.extend(args.model.effects.iter().map(|p| p.as_path()));
    let mut outputs = crate::output::Outputs::new(&inputs, args.force);
    crate::output::check_output_dir(dir, "--export")?;
    let header = crate::output::Made::Csv(rung_header());
    for k in 0..rungs {
        let p = dir.join(format!("rung{k}.csv"));
        if dir.is_dir() {
            outputs.check(&p, "--export", header.clone())?;
        }
    }
    if dir.is_dir() {
        outputs.check(
            &dir.join("rungs.csv"),
            "--export",
            crate::output::Made::Csv(INDEX_HEADER.into()),
        )?;
        outputs.check(
            &dir.join("coefficients.csv"),
            "--export",
            crate::output::Made::Csv(COEFFICIENTS_HEADER.into()),
        )?;
    }
    Ok(())
}

/// Writes each rung's series (`rungK.csv`) and a summary (`rungs.csv`) into `dir`, all whole
/// or none (checked first by [`check_export`]).
pub(crate) fn export(
    dir: &std::path::Path,
    diagnoses: &[Diagnosis],
    coefficients: &[super::identify::Row],
) -> anyhow::Result<()> {
    use std::fmt::Write as _;
    std::fs::create_dir_all(dir).with_context(|| format!("{}", dir.display()))?;
    let mut index = format!("{INDEX_HEADER}\n");
    let mut files: Vec<(std::path::PathBuf, String)> = Vec::with_capacity(diagnoses.len() + 1);
    for (k, d) in diagnoses.iter().enumerate() {
        let model = model_name_compact(&d.model);
        let _ = writeln!(
            index,
            "{k},{model},{},{},{},{},{},{}",
            d.residual_rms_over_floor[0],
            d.residual_rms_over_floor[1],
            d.residual_rms_over_floor[2],
            d.nis_mean,
            d.whiteness.p_value,
            d.consistency.is_consistent()
        );
        let s = &d.series;
        let mut csv = rung_header();
        csv.push('\n');
        for j in 0..s.t_h.len() {
            let _ = write!(csv, "{}", s.t_h[j]);
            for q in [
                &s.measured,
                &s.predicted,
                &s.residual,
                &s.innovation,
                &s.innovation_sigma,
            ] {
                for v in q[j] {
                    let _ = write!(csv, ",{v}");
                }
            }
            for v in s.whitened[j] {
                let _ = write!(csv, ",{v}");
            }
            let _ = writeln!(csv, ",{}", s.nis[j]);
        }
        files.push((dir.join(format!("rung{k}.csv")), csv));
    }
    files.push((dir.join("rungs.csv"), index));
    let mut coefs = format!("{COEFFICIENTS_HEADER}\n");
    for r in coefficients {
        let _ = writeln!(
            coefs,
            "{},{},{},{},{},{},{}",
            r.name, r.unit, r.value, r.sigma_total, r.sigma, r.bound, r.dominant
        );
    }
    files.push((dir.join("coefficients.csv"), coefs));
    // All written to temporaries first, then moved into place: an error (a full disk) leaves
    // the earlier export as it was, not half old and half new.
    let mut done = Vec::with_capacity(files.len());
    for (target, text) in &files {
        let mut f = crate::output::AtomicFile::create(target)?;
        std::io::Write::write_all(&mut f, text.as_bytes())
            .with_context(|| format!("writing {}", target.display()))?;
        done.push(f);
    }
    for f in done {
        f.commit()?;
    }
    println!(
        "wrote {} rung files, rungs.csv and coefficients.csv to {}",
        diagnoses.len(),
        dir.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::stopped_at_the_cap;
    use crate::diagnose::select::Choice;
    use crate::diagnose::verdict::tests::diagnosis;
    use std::path::Path;

    /// A rung of model `model` whose evidence still chooses `next`.
    fn rung(model: &[&str], next: Option<&str>) -> crate::diagnose::Diagnosis {
        let mut d = diagnosis(1.0, 0.5, 1.0);
        d.model = model.iter().map(|m| m.to_string()).collect();
        d.choice = next.map(|e| Choice {
            effect: e.into(),
            reason: format!("`{e}` is the only candidate whose refit gains evidence (159.5)"),
            profiled: None,
            confounded: None,
        });
        d
    }

    /// A ladder cut by its cap with an effect still chosen is a reason not to trust it, naming the
    /// effect and the command that goes on from the last model (its catalog effects only: `--with`
    /// refuses a warm-up made for the run); a ladder that stopped by itself, or one kept to a
    /// single rung (`--no-ladder`, a fault), is not.
    #[test]
    fn a_ladder_cut_short_by_its_cap_says_how_to_go_on() {
        let run = Path::new("q1_2.csv");
        let cut = [
            rung(&[], Some("acc-bias")),
            rung(&["acc-bias"], Some("acc-scale")),
            rung(&["acc-bias", "acc-scale"], Some("acc-misalign")),
        ];
        let why = stopped_at_the_cap(&cut, run, 3).expect("cut by the cap");
        assert!(why.contains("stopped at its 3 models"), "{why}");
        assert!(
            why.contains("`acc-misalign` is the only candidate"),
            "{why}"
        );
        assert!(
            why.contains("`driftid diagnose q1_2.csv --with acc-bias,acc-scale`"),
            "{why}"
        );
        assert_eq!(
            stopped_at_the_cap(&cut, run, 4),
            None,
            "the cap not reached"
        );
        // An effect made for the run (profiled) is not one `--with` takes: the ladder makes it again.
        let mut made = cut.clone();
        made[1].choice.as_mut().unwrap().profiled =
            Some(crate::diagnose::select::Profiled::WarmupTauS(10_800.0));
        made[2].model = vec!["acc-bias".into(), "drift-warmup".into()];
        made[1].choice.as_mut().unwrap().effect = "drift-warmup".into();
        let why = stopped_at_the_cap(&made, run, 3).expect("cut by the cap");
        assert!(
            why.contains("`driftid diagnose q1_2.csv --with acc-bias` goes on from its catalog effects (the ladder makes drift-warmup for the run again)"),
            "{why}"
        );
        let done = [rung(&[], Some("acc-bias")), rung(&["acc-bias"], None)];
        assert_eq!(stopped_at_the_cap(&done, run, 2), None, "stopped by itself");
        assert_eq!(
            stopped_at_the_cap(&cut[..1], run, 1),
            None,
            "one rung asked for"
        );
    }
}
