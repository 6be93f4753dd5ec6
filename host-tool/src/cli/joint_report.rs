//! `driftid report A.csv B.csv …`: the joint fit of several runs (the fit of `driftid identify
//! A.csv B.csv`, [`super::joint::fit_runs`]) as one self-contained HTML page (and PNGs).

use super::joint::{deg3, fit_runs, weak_line, JointFit};
use super::report::{provenance, ReportArgs};
use crate::catalog::Catalog;
use crate::output;
use crate::report::{draw_joint_pngs, render_joint_html, JointCoef, JointReportInput, JointRun};

/// Runs `driftid report` on several recordings: exit status as the joint `identify`'s (0
/// trusted, 3 untrusted, 2 bad input).
pub(crate) fn run(args: &ReportArgs, catalog: &Catalog) -> anyhow::Result<()> {
    // Every output checked before the long computation (never over an input or a file driftid
    // did not write), as for one run.
    let mut inputs: Vec<&std::path::Path> = args.recordings.iter().map(|p| p.as_path()).collect();
    inputs.extend(args.truth.as_deref());
    inputs.extend(args.model.effects.iter().map(|p| p.as_path()));
    let mut outputs = output::Outputs::new(&inputs, args.force);
    outputs.check(&args.out, "--out", output::Made::Html)?;
    if let Some(dir) = &args.png {
        output::check_output_dir(dir, "--png")?;
    }
    anyhow::ensure!(
        args.model.config()?.smoother_iterations > 0,
        "report needs the converged identification; drop --single-pass"
    );
    let fit = fit_runs(
        catalog,
        &args.recordings,
        &args.model,
        &args.model.with,
        args.truth.as_deref(),
    )?;
    for r in &fit.runs {
        println!("{}:", r.path.display());
        super::common::print_findings(&r.prep.findings);
    }
    let input = page_input(&fit, &args.model.with, &args.model.effects);
    let html = render_joint_html(&input)?;
    let pngs = match &args.png {
        Some(dir) => draw_joint_pngs(&input, dir, &mut outputs)?,
        None => vec![],
    };
    super::report::write_page(args, &html, pngs)?;
    super::common::trusted_or(fit.reasons)
}

/// What the joint page shows of the fit: each run under the joint estimate
/// ([`crate::diagnose::of_joint_run`]), the shared coefficients, the weakest combinations.
fn page_input(
    fit: &JointFit,
    with: &[String],
    effects_files: &[std::path::PathBuf],
) -> JointReportInput {
    let lags = crate::diagnose::DiagnoseConfig::default().lags;
    let model: Vec<String> = with.to_vec();
    let name = |p: &std::path::Path| {
        p.file_name()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default()
    };
    let runs = fit
        .runs
        .iter()
        .zip(&fit.joint.runs)
        .map(|(r, f)| JointRun {
            recording: name(&r.path),
            description: r.description.clone(),
            orientation_deg: deg3(&r.orientation_rad),
            chart: format!("{:?}", r.prep.site.chart),
            hours: f.alone.final_time_h,
            diagnosis: crate::diagnose::of_joint_run(&r.prep, model.clone(), f, lags),
            findings: r.prep.findings.clone(),
        })
        .collect();
    let e = &fit.joint.estimate;
    let coefficients = fit
        .joint
        .params
        .iter()
        .enumerate()
        .map(|(k, p)| JointCoef {
            name: p.name.to_string(),
            unit: p.unit.to_string(),
            value: e.value[k],
            sigma: fit.noise_sigma[k],
            sigma_total: fit.total_sigma[k],
            bound: fit.bound[k],
            best_alone: fit
                .joint
                .runs
                .iter()
                .map(|f| f.alone.best().sigma(k))
                .fold(f64::INFINITY, f64::min),
            truth: fit.truth.as_ref().map(|t| t[k]),
        })
        .collect();
    JointReportInput {
        title: format!(
            "Gyro drift identification — {} runs jointly",
            fit.runs.len()
        ),
        model,
        runs,
        coefficients,
        weak: fit.joint.weak.iter().map(weak_line).collect(),
        untrusted: fit.reasons.clone(),
        provenance: provenance(effects_files),
    }
}
