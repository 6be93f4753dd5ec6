//! `driftid report`: the whole story of a recording as one self-contained HTML page (and PNGs).

use std::path::PathBuf;

use super::common::ModelArgs;
use super::identify::rows;
use crate::catalog::Catalog;
use crate::diagnose::DiagnoseConfig;
use crate::output;
use crate::report::{draw_pngs, render_html, CoefRow, ReportInput};
use crate::simulate::read_truth;

/// Arguments of `driftid report`.
#[derive(clap::Args, Debug)]
pub struct ReportArgs {
    /// Recording(s) (CSV). Several runs of one system: a report of their joint fit, the fit of
    /// `driftid identify A.csv B.csv` (each run's residual and consistency, the shared
    /// coefficients).
    #[arg(required = true, num_args = 1..)]
    pub recordings: Vec<PathBuf>,
    /// Output HTML file.
    #[arg(short = 'o', long, default_value = "report.html")]
    pub out: PathBuf,
    /// Also write each plot as a PNG into this folder.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Truth file of a simulated run: adds truth and error columns.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Replace an existing --out or PNG that is not a file driftid wrote.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub model: ModelArgs,
}

/// Runs `driftid report`.
pub fn run(args: &ReportArgs) -> anyhow::Result<()> {
    // --effects FILE: the user's effects join the catalog of this run.
    let catalog = super::common::catalog(&args.model)?;
    let result = if args.recordings.len() > 1 {
        super::joint_report::run(args, &catalog)
    } else {
        run_one(args, &catalog)
    };
    super::common::unless_numeric_failure(&catalog, result)
}

/// `driftid report` of one recording.
fn run_one(args: &ReportArgs, catalog: &Catalog) -> anyhow::Result<()> {
    let recording = &args.recordings[0];
    let mut outputs = checked_outputs(args)?;
    let mut cfg = DiagnoseConfig {
        identify: args.model.config()?,
        ..Default::default()
    };
    anyhow::ensure!(
        cfg.identify.smoother_iterations > 0,
        "report needs the converged identification; drop --single-pass"
    );
    let c = super::diagnose::climb(catalog, recording, &args.model, &mut cfg)?;
    super::common::print_findings(&c.prep.findings);
    let model = super::common::build_model(c.prep.site, &c.final_effects, &cfg.identify)?;
    let mut untrusted =
        super::diagnose::ladder_untrusted(&c.faults, &c.diagnoses, (recording, cfg.max_rungs));
    let assessed = c.assessed;
    let truth = match &args.truth {
        Some(p) => Some(super::identify::truth_of(
            &read_truth(p)?,
            &assessed.id.params,
        )),
        None => None,
    };
    untrusted.extend(assessed.reasons.iter().cloned());
    let table = rows(
        &assessed.id,
        &assessed.unc,
        &assessed.alternatives,
        &model,
        &assessed.prep,
        truth.as_deref(),
    );
    let name = recording
        .file_name()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    let input = ReportInput {
        title: format!("Gyro drift identification — {name}"),
        recording: name,
        description: c.description,
        diagnoses: c.diagnoses,
        ladder: c.rungs,
        coefficients: coefficient_rows(&table, truth.as_deref()),
        findings: assessed.prep.findings.clone(),
        untrusted: untrusted.clone(),
        provenance: provenance(&args.model.effects),
        markov: assessed.id.markov,
    };
    let html = render_html(&input)?;
    let pngs = match &args.png {
        Some(dir) => draw_pngs(&input, dir, &mut outputs)?,
        None => vec![],
    };
    write_page(args, &html, pngs)?;
    super::common::trusted_or(untrusted)
}

/// Every output checked before the long computation, and all are drawn before any is moved
/// into place: never over an input or a file driftid did not write, and no HTML left behind
/// when a PNG cannot be written.
fn checked_outputs(args: &ReportArgs) -> anyhow::Result<output::Outputs> {
    let mut inputs: Vec<&std::path::Path> = vec![&args.recordings[0]];
    inputs.extend(args.truth.as_deref());
    inputs.extend(args.model.effects.iter().map(|p| p.as_path()));
    let mut outputs = output::Outputs::new(&inputs, args.force);
    outputs.check(&args.out, "--out", output::Made::Html)?;
    if let Some(dir) = &args.png {
        output::check_output_dir(dir, "--png")?;
    }
    Ok(outputs)
}

/// The coefficient table's rows as the page shows them, with the truth where it is finite.
fn coefficient_rows(table: &[super::identify::Row], truth: Option<&[f64]>) -> Vec<CoefRow> {
    table
        .iter()
        .enumerate()
        .map(|(k, r)| CoefRow {
            name: r.name.to_string(),
            unit: r.unit.to_string(),
            value: r.value,
            sigma: r.sigma,
            sigma_total: r.sigma_total,
            dominant: r.dominant.to_string(),
            bound: r.bound,
            truth: truth
                .and_then(|t| t.get(k).copied())
                .filter(|v| v.is_finite()),
            conditional_on: r.conditional_on.clone(),
        })
        .collect()
}

/// Writes the page to `args.out` and commits the PNG plots drawn for `args.png` (each whole or
/// not at all), saying what was written.
pub(crate) fn write_page(
    args: &ReportArgs,
    html: &str,
    pngs: Vec<output::TempPath>,
) -> anyhow::Result<()> {
    let mut page = output::AtomicFile::create(&args.out)?;
    std::io::Write::write_all(&mut page, html.as_bytes())
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", args.out.display()))?;
    page.commit()?;
    println!("wrote {}", args.out.display());
    if let Some(dir) = &args.png {
        let n = pngs.len();
        for p in pngs {
            p.commit()?;
        }
        println!("wrote {n} PNG plots to {}", dir.display());
    }
    Ok(())
}

/// The command line as given and each effects file's text (what made the page).
pub(crate) fn provenance(effects: &[std::path::PathBuf]) -> crate::report::Provenance {
    let quote = |a: String| {
        if a.is_empty() || a.contains(|c: char| c.is_whitespace() || "'\"$`\\".contains(c)) {
            format!("'{}'", a.replace('\'', "'\\''"))
        } else {
            a
        }
    };
    crate::report::Provenance {
        command: std::env::args_os()
            .map(|a| quote(a.to_string_lossy().into_owned()))
            .collect::<Vec<_>>()
            .join(" "),
        effects_files: effects
            .iter()
            .map(|p| {
                let text =
                    std::fs::read_to_string(p).unwrap_or_else(|e| format!("(unreadable: {e})"));
                (p.display().to_string(), text)
            })
            .collect(),
    }
}
