//! `driftid identify`: the drift coefficients of a recording, with 1σ and the Cramér–Rao bound.

use std::path::PathBuf;

use serde_json::{json, Map, Value};

use super::common::{build_model, load, print_findings, trusted_or, ModelArgs};
use crate::catalog::Catalog;
use crate::consistency::Consistency;
use crate::format::{sci, with_sigma};
use crate::identify::setup::Uncertainty;
use crate::identify::{try_cramer_rao_bound, Identification, Prepared};
use crate::simulate::read_truth;

/// Arguments of `driftid identify`.
#[derive(clap::Args, Debug)]
pub struct IdentifyArgs {
    /// Recording(s) (CSV, see docs/recording-format.md). Several runs of the same system are
    /// identified jointly: one set of coefficients, each run with its own attitude and noise.
    #[arg(required = true, num_args = 1..)]
    pub recordings: Vec<PathBuf>,
    /// Truth file of a simulated run (`NAME.truth.json`): adds error and error/σ columns.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub model: ModelArgs,
}

/// One coefficient row of the output.
pub(crate) struct Row {
    /// Parameter name.
    pub name: &'static str,
    /// Unit.
    pub unit: &'static str,
    /// Estimate.
    pub value: f64,
    /// 1σ with the set-up exactly as stated (noise only; the bound's counterpart).
    pub sigma: f64,
    /// 1σ with the set-up's priors ([`crate::identify::setup`]): the headline.
    pub sigma_total: f64,
    /// The set-up source that adds most (`noise` when none adds as much as the noise).
    pub dominant: &'static str,
    /// Cramér–Rao bound 1σ (at the truth if known, else at the estimate).
    pub bound: f64,
    /// The paper's single-pass estimate and its claimed 1σ.
    pub single: Option<(f64, f64)>,
    /// True value, if known.
    pub truth: Option<f64>,
    /// The alternatives it holds only on the absence of, with how far each could move it (total
    /// 1σ; [`crate::diagnose::alternatives::conditional_on`]).
    pub conditional_on: Vec<(String, f64)>,
}

/// The true value of each of the identification's parameters (NaN where the truth file has none:
/// an effect not injected is 0, a Gauss–Markov state has no fixed truth).
pub(crate) fn truth_of(
    truth: &crate::simulate::Truth,
    params: &[estimator_core::effects::Param],
) -> Vec<f64> {
    let values = truth.parameter_values();
    params
        .iter()
        .map(|p| match values.get(p.name) {
            Some(v) => *v,
            None if known_zero(p.name) => 0.0,
            None => f64::NAN,
        })
        .collect()
}

/// Whether a parameter the simulator did not inject is truly zero: a parameter of a built-in
/// effect (the paper's, the catalog's, the drift step's, the warm-up's) that is no Gauss–Markov
/// state. A Gauss–Markov state is a random process, and an effects-file parameter is named by
/// the user (the simulator's own effects outside the catalog, such as `acc-north`, are not
/// matched to it): their truth is unknown (NaN), not 0 — the error column was wrong for them.
fn known_zero(name: &str) -> bool {
    let deterministic = |e: &dyn estimator_core::effects::Effect| {
        (0..e.params().len()).any(|k| e.params()[k].name == name && e.markov(k).is_none())
    };
    crate::catalog::builtin_candidates()
        .into_iter()
        .chain([crate::catalog::paper()])
        .any(deterministic)
        || crate::diagnose::drift_step::PARAMS
            .iter()
            .chain(&crate::diagnose::warmup::PARAMS)
            .chain(&crate::diagnose::periodic::PARAMS)
            .any(|p| p.name == name)
}

/// Builds the rows of an identification (bound at `truth` where it is known, NaN entries
/// meaning unknown).
pub(crate) fn rows(
    id: &Identification,
    unc: &Uncertainty,
    alts: &[crate::diagnose::alternatives::Alternative],
    model: &estimator_core::Model<'_>,
    prep: &Prepared,
    truth: Option<&[f64]>,
) -> Vec<Row> {
    let best = id.best();
    let bound_at: Vec<f64> = (0..best.value.len())
        .map(|k| {
            truth
                .and_then(|t| t.get(k).copied())
                .filter(|v| v.is_finite())
                .unwrap_or(best.value[k])
        })
        .collect();
    // The bound is printed beside the estimate; where the linearised filter breaks down on
    // these measurements it is shown as n/a, with a warning, rather than ending the run.
    let bound = try_cramer_rao_bound(model, prep, &bound_at).unwrap_or_else(|e| {
        eprintln!("driftid: warning: no Cramér–Rao bound: {e:#}");
        vec![f64::NAN; best.value.len()]
    });
    (0..best.value.len())
        .map(|k| Row {
            name: id.params[k].name,
            unit: id.params[k].unit,
            value: best.value[k],
            sigma: unc.noise_sigma[k],
            sigma_total: unc.total_sigma[k],
            dominant: unc.dominant(k),
            bound: bound[k],
            single: id.single_pass.as_ref().map(|s| (s.value[k], s.sigma(k))),
            truth: truth
                .and_then(|t| t.get(k).copied())
                .filter(|v| v.is_finite()),
            conditional_on: crate::diagnose::alternatives::conditional_on(
                alts,
                &unc.total_sigma,
                k,
            ),
        })
        .collect()
}

/// Prints the coefficient table.
pub(crate) fn print_table(rows: &[Row], refined: bool) {
    let has_truth = rows.iter().any(|r| r.truth.is_some());
    // Columns that do not shift with a long parameter name (`GXxx-zz`): the name column is as
    // wide as the longest name, 6 at least (the paper's names keep their layout).
    let w = rows
        .iter()
        .map(|r| r.name.chars().count())
        .fold(6, usize::max);
    print!(
        "{:<w$} {:<16} {:>12} {:>10} {:>10} {:>10} {:>6} {:<15}",
        "coef", "unit", "estimate", "1σ total", "noise 1σ", "CRB 1σ", "ratio", "most from"
    );
    if has_truth {
        print!(
            " {:>10} {:>10} {:>8} {:>7}",
            "truth", "error", "error %", "err/σ"
        );
    }
    println!("  {:>12} {:>9}", "single pass", "its 1σ");
    for r in rows {
        print!(
            "{:<w$} {:<16} {:>12} {:>10} {:>10} {:>10} {:>6.2} {:<15}",
            r.name,
            r.unit,
            with_sigma(r.value, r.sigma_total),
            sci(r.sigma_total),
            sci(r.sigma),
            sci(r.bound),
            r.sigma_total / r.sigma,
            r.dominant
        );
        if let Some(t) = r.truth {
            let e = r.value - t;
            // Relative to the truth's size: the sign is the error's, whatever the truth's sign.
            let pct = if t != 0.0 {
                format!("{:.3}", 100.0 * e / t.abs())
            } else {
                "-".into()
            };
            print!(
                " {:>10} {:>10} {:>8} {:>7.2}",
                crate::format::sig(t, 7),
                sci(e),
                pct,
                e / r.sigma_total
            );
        } else if has_truth {
            print!(" {:>10} {:>10} {:>8} {:>7}", "—", "", "", "");
        }
        match r.single {
            Some((v, s)) => println!("  {:>12} {:>9}", with_sigma(v, s), sci(s)),
            // The paper's pass diverged on this recording; the smoother fitted without it.
            None => println!("  {:>12} {:>9}", "—", "—"),
        }
    }
    if !refined {
        println!("(single pass only: its 1σ is optimistic on the paper's scenario; drop --single-pass for the converged estimate)");
    }
}

/// Prints the run summary and weak-combination warnings.
pub(crate) fn print_summary(id: &Identification, prep: &Prepared) {
    let rms = id.residual_rms_mps2(prep);
    let floor = prep.floor_mps2();
    let typical = crate::quality::steps::typical_count(&prep.measurements);
    println!(
        "run: {:.2} h, {} updates; noise floor per {}-sample mean [{}] m/s^2; residual RMS [{}, {}, {}] m/s^2; mean NIS/3 {:.3} (1 when consistent)",
        id.final_time_h,
        prep.measurements.len(),
        typical,
        floor.map(sci).join(", "),
        sci(rms[0]),
        sci(rms[1]),
        sci(rms[2]),
        id.nis_mean()
    );
    for w in &id.weak {
        if w.ratio_to_next >= 10.0 {
            println!(
                "warning: axis {} — the combination {:.2}·D0 {:+.2}·g·Dx {:+.2}·g·Dy {:+.2}·g·Dz is {:.0}x weaker than the next (1σ {} deg/h): \
                 on a static run only the drift-induced turn of the platform separates it; a longer run or another \
                 initial orientation would pin it down (`driftid plan RUN.csv` recommends one)",
                w.axis, w.direction[0], w.direction[1], w.direction[2], w.direction[3], w.ratio_to_next, sci(w.sigma_degph)
            );
        }
    }
}

/// Prints the alternative explanations: evidence, weight, and the coefficients each could move
/// beyond their total 1σ at a size the run cannot rule out.
pub(crate) fn print_alternatives(
    alts: &[crate::diagnose::alternatives::Alternative],
    unc: &Uncertainty,
    id: &Identification,
) {
    if alts.is_empty() {
        return;
    }
    println!("alternative explanations (catalog effects not in the model, a misstated set-up; evidence gain in −2 ln units, > 0: the data prefer it):");
    let mut any_conditional = false;
    let width = alts
        .iter()
        .map(|a| a.label().chars().count())
        .max()
        .unwrap_or(0)
        .max(20);
    for a in alts {
        let conditional: Vec<String> = a
            .reaches_beyond(&unc.total_sigma)
            .into_iter()
            .filter(|&(k, _)| k < id.params.len())
            .map(|(k, z)| format!("{} ({z:.1}σ)", id.params[k].name))
            .collect();
        any_conditional |= !conditional.is_empty();
        println!(
            "  {:<width$} evidence gain {:>10.1}  weight {:.3}  {}",
            a.label(),
            a.evidence_gain,
            a.weight,
            if conditional.is_empty() {
                "moves no coefficient beyond its total 1σ at any size this run cannot rule out"
                    .to_string()
            } else {
                format!(
                    "could move, at a size this run cannot rule out: {}",
                    conditional.join(", ")
                )
            }
        );
    }
    if any_conditional {
        println!("  (such a coefficient holds only on that effect's absence: a second run from another orientation, `driftid plan`, or a bench value of the effect settles it)");
    }
}

/// Prints what each set-up prior adds (the largest share over the coefficients).
pub(crate) fn print_setup(unc: &Uncertainty, id: &Identification) {
    if unc.contributions.is_empty() {
        return;
    }
    println!(
        "set-up uncertainty (1σ total = noise ⊕ these; docs/model.md, \"Set-up parameters\"):"
    );
    for c in &unc.contributions {
        let (k, worst) = c
            .sigma
            .iter()
            .enumerate()
            .map(|(k, s)| (k, s / unc.noise_sigma[k]))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((0, 0.0));
        let data = match (c.offset, c.stated) {
            (Some(o), Some((v, unit))) => {
                // The estimate with the 1σ the run supports (the slow drifts free where that is
                // wider), the narrower ones beside it.
                format!(
                    "; estimated {} {unit}{} (stated {}{}{})",
                    crate::format::pm(v + o, c.knob_sigma()),
                    if c.sigma_drifts_free.is_some() {
                        " with the slow drifts free"
                    } else {
                        ""
                    },
                    crate::format::sig(v, 9),
                    c.sigma_drifts_free
                        .map(|_| format!("; ± {} were they absent", sci(c.posterior_sigma)))
                        .unwrap_or_default(),
                    c.data_sigma
                        .map(|s| format!("; the data alone ± {}", sci(s)))
                        .unwrap_or_default()
                )
            }
            _ => String::new(),
        };
        println!(
            "  {:<15} prior {:<28} adds up to {:.2} × the noise 1σ ({}){data}",
            c.source,
            c.prior,
            worst,
            id.params.get(k).map_or("", |p| p.name)
        );
    }
}

/// The JSON object of an identification.
pub(crate) fn to_json(rows: &[Row], id: &Identification, prep: &Prepared) -> Value {
    let coefs = coefficients_json(rows);
    json!({
        "coefficients": coefs,
        "final_time_h": id.final_time_h,
        "updates": prep.measurements.len(),
        "residual_rms_mps2": id.residual_rms_mps2(prep),
        "nis_mean": id.nis_mean(),
        "raw_noise_sigma_mps2": prep.noise.raw_sigma_mps2,
        "method": if id.refined.is_some() { "two EKF passes + iterated RTS smoother (Gauss-Newton to 0.01σ; see convergence)" } else { "single EKF pass" },
        "weak_combinations": id.weak,
        "data_quality": { "findings": prep.findings },
    })
}

/// The coefficients as JSON: value, `sigma` (noise only), `sigma_total` (the headline), the
/// bound, the unit, the single pass and the truth where known.
pub(crate) fn coefficients_json(rows: &[Row]) -> Value {
    let mut coefs = Map::new();
    for r in rows {
        let mut o = json!({ "value": r.value, "sigma": r.sigma, "sigma_total": r.sigma_total,
            "dominant_uncertainty": r.dominant, "bound": r.bound, "unit": r.unit,
            "single_pass": r.single.map(|(v, s)| json!({ "value": v, "sigma": s })),
            "conditional_on": r.conditional_on.iter()
                .map(|(e, z)| json!({ "effect": e, "reach_total_sigma": z }))
                .collect::<Vec<_>>() });
        if let Some(t) = r.truth {
            o["truth"] = json!(t);
            o["error"] = json!(r.value - t);
        }
        coefs.insert(r.name.to_string(), o);
    }
    Value::Object(coefs)
}

/// Runs `driftid identify`.
pub fn run(args: &IdentifyArgs) -> anyhow::Result<()> {
    // --effects FILE: the user's effects join the catalog of this run.
    let catalog = super::common::catalog(&args.model)?;
    let result = if args.recordings.len() > 1 {
        super::joint::run(args, &catalog)
    } else {
        run_one(args, &catalog)
    };
    super::common::unless_numeric_failure(&catalog, result)
}

/// `driftid identify` of one recording.
fn run_one(args: &IdentifyArgs, catalog: &Catalog) -> anyhow::Result<()> {
    let recording = &args.recordings[0];
    let cfg = args.model.config()?;
    let loaded = load(catalog, recording, args.model.latitude_deg)?;
    let effects = catalog.model_effects(&args.model.with)?;
    let prep = super::common::prepare_loaded(recording, &loaded, &cfg)?;
    // The raw samples are done with (the measurements are their means): freed now, their
    // ~10 MB (60 h at 1 s) serve the smoother's buffers instead of fresh pages faulted in.
    drop(loaded);
    let spin = crate::progress::spinner("identifying (2 EKF passes + iterated smoother)");
    let id = crate::diagnose::latitude::fit_or_name_the_latitude(&prep, &effects, &cfg)?;
    spin.finish_and_clear();
    // drift-markov in the model: its σ and τ from the data, the model refitted there.
    let (effects, id) = crate::identify::markov::tune(catalog, &prep, &effects, &cfg, id)?;
    let spin =
        crate::progress::spinner("the set-up's uncertainty and the alternative explanations");
    let progress = crate::progress::follow(&spin);
    // The measurements at the stated set-up: a repair starts again from them.
    let stated = prep.clone();
    let assessed = crate::assess::assess_with(catalog, &effects, prep, &cfg, id, None, &progress)?;
    // A misfit: a drift step profiled, and beside it the latitude (on this fit; again on the
    // repaired one should the step be repaired). The step is repaired when it explains the
    // misfit better than anything else.
    let (step, latitude) = rayon::join(
        || crate::assess::drift_step_on_a_misfit(&effects, &cfg, &assessed, &progress),
        || wrong_latitude_on_a_misfit(catalog, &effects, &cfg, &assessed, &progress),
    );
    let crate::assess::StepJudged {
        effects,
        assessed,
        step,
        repaired,
    } = crate::assess::repaired_if_it_wins(
        catalog,
        stated,
        effects,
        &cfg,
        (assessed, step),
        &progress,
    )?;
    spin.finish_and_clear();
    // A repair tunes the wander again where it puts the set-up.
    let effects = catalog.as_tuned(&effects, &assessed.id);
    let truth = match &args.truth {
        Some(p) => Some(truth_of(&read_truth(p)?, &assessed.id.params)),
        None => None,
    };
    let model = build_model(assessed.prep.site, &effects, &cfg)?;
    let rows = rows(
        &assessed.id,
        &assessed.unc,
        &assessed.alternatives,
        &model,
        &assessed.prep,
        truth.as_deref(),
    );
    let check = consistency_of(&assessed.id, &assessed.prep);
    let mut assessed = assessed;
    if repaired {
        // The repaired model still does not fit: is the metadata latitude the culprit?
        let found = wrong_latitude_on_a_misfit(catalog, &effects, &cfg, &assessed, &progress);
        assessed.prep.findings.extend(found);
    } else {
        assessed.prep.findings.extend(latitude);
    }
    let (reasons, step) = untrusted(&mut assessed, step, check.as_ref());
    let a = &assessed;
    if args.json {
        let out = identify_json(a, &rows, check.as_ref(), step.as_ref(), &reasons)?;
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_text(recording, a, &rows, &reasons);
    }
    trusted_or(reasons)
}

/// Whether the metadata latitude is why the assessed fit does not fit
/// ([`super::common::name_a_wrong_latitude`], against the catalog's refitted rivals and the
/// misstated set-ups, [`super::common::latitude_rivals`]); `None` when it
/// fits.
fn wrong_latitude_on_a_misfit(
    catalog: &Catalog,
    effects: &[&dyn estimator_core::effects::Effect],
    cfg: &crate::identify::Config,
    assessed: &crate::assess::Assessment,
    progress: &crate::steps::Progress,
) -> Option<crate::quality::Finding> {
    let misfit = consistency_of(&assessed.id, &assessed.prep).is_some_and(|c| !c.is_consistent());
    if !misfit {
        return None;
    }
    let (prep, id) = (&assessed.prep, &assessed.id);
    let rivals =
        |p: &Prepared| super::common::latitude_rivals(p, catalog, effects, cfg, id, progress);
    super::common::name_a_wrong_latitude(prep, (effects, id), cfg, rivals, progress)
}

/// Why the estimate is not trusted (empty: trusted): the data's faults, convergence, the
/// assessment's reasons (taken from `a`), a drift step when it beats every alternative and no
/// wrong latitude was named (returned, else `None`), a misfit, or a single pass.
fn untrusted(
    a: &mut crate::assess::Assessment,
    step: Option<crate::diagnose::drift_step::DriftStepFit>,
    check: Option<&Consistency>,
) -> (
    Vec<String>,
    Option<crate::diagnose::drift_step::DriftStepFit>,
) {
    let mut reasons = a.prep.untrusted_reasons();
    reasons.extend(a.id.convergence.and_then(|c| c.untrusted_reason()));
    reasons.append(&mut a.reasons);
    let metadata_named = a
        .prep
        .findings
        .iter()
        .any(|f| f.kind == crate::quality::Kind::Latitude);
    let step = step.filter(|s| !metadata_named && s.beats(&a.alternatives));
    if let Some(s) = &step {
        reasons.push(s.reason());
    }
    match check {
        Some(c) if !c.is_consistent() && !metadata_named => reasons.push(format!(
            "the model does not explain the measurements: {}; run `driftid diagnose` to find the missing effect",
            c.failures.join("; ")
        )),
        Some(_) => {}
        None => reasons.push(
            "single EKF pass (the paper's method): its 1σ claims far more than it knows; drop --single-pass for a trusted estimate".into(),
        ),
    }
    (reasons, step)
}

/// The identification as one JSON object (`--json`).
fn identify_json(
    a: &crate::assess::Assessment,
    rows: &[Row],
    check: Option<&Consistency>,
    step: Option<&crate::diagnose::drift_step::DriftStepFit>,
    reasons: &[String],
) -> anyhow::Result<Value> {
    let mut out = to_json(rows, &a.id, &a.prep);
    out["consistency"] = serde_json::to_value(check)?;
    out["setup_uncertainty"] = serde_json::to_value(&a.unc.contributions)?;
    out["alternatives"] = serde_json::to_value(&a.alternatives)?;
    out["convergence"] = serde_json::to_value(a.id.convergence)?;
    if let Some(gm) = &a.id.markov {
        out["drift_markov"] = serde_json::to_value(gm)?;
    }
    if let Some(s) = step {
        out["drift_step"] = serde_json::to_value(s)?;
    }
    out["trusted"] = json!(reasons.is_empty());
    out["untrusted_reasons"] = json!(reasons);
    Ok(out)
}

/// The identification as text: findings, the coefficients' table, the fit's summary, the
/// set-up's uncertainty, the alternatives and why it is not trusted.
fn print_text(
    recording: &std::path::Path,
    a: &crate::assess::Assessment,
    rows: &[Row],
    reasons: &[String],
) {
    let (id, prep) = (&a.id, &a.prep);
    print_findings(&prep.findings);
    println!(
        "{}: drift coefficients ({})",
        recording.display(),
        if id.refined.is_some() {
            "converged: 2 EKF passes + iterated RTS smoother"
        } else {
            "single EKF pass"
        }
    );
    print_table(rows, id.refined.is_some());
    print_summary(id, prep);
    if let Some(gm) = &id.markov {
        println!("{}", gm.line());
    }
    print_setup(&a.unc, id);
    print_alternatives(&a.alternatives, &a.unc, id);
    if !reasons.is_empty() {
        println!("NOT TRUSTED: the numbers above are computed but the tool does not trust them:");
        for r in reasons {
            println!("  - {r}");
        }
    } else {
        print_trusted_on(rows, &recording.display().to_string());
    }
}

/// A trusted result's conditions, said last where a reader stops: the alternatives its drift
/// coefficients hold only on the absence of (`Row::conditional_on`), the farthest-reaching
/// first, and how to settle them (`recording` names the run for the `driftid plan` line).
pub(crate) fn print_trusted_on(rows: &[Row], recording: &str) {
    let on = crate::diagnose::alternatives::held_on(
        rows.iter().map(|r| (r.name, r.conditional_on.as_slice())),
    );
    let Some(words) = crate::diagnose::alternatives::held_on_words(&on) else {
        println!("trusted: no alternative this run cannot rule out moves a drift coefficient beyond its total 1σ");
        return;
    };
    let catalog = on
        .iter()
        .find(|(e, _, _)| crate::catalog::Catalog::builtin().by_name(e).is_some())
        .map(|(e, _, _)| *e);
    println!(
        "trusted on the absence of what this run cannot rule out: {words} (the alternatives above){}",
        catalog.map_or(String::new(), |e| format!(
            "; `driftid plan {recording} --with {e}` designs the run that separates it, or a bench value settles it"
        ))
    );
}

pub use crate::consistency::{consistency_of, fit_consistency};
