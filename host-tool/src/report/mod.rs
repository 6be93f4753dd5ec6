//! The report: one self-contained HTML page that tells the whole story of a recording — model
//! against data, where it fails, which effect is missing, the model ladder and the error falling,
//! and the identified coefficients with 1σ and the Cramér–Rao bound.
//!
//! Plots are inline SVG drawn by [`plots`] (plotters' SVG backend, text measured with an embedded
//! font); the page loads nothing from the network and needs no system font. The same figures can
//! be written as PNG files ([`draw_pngs`]).

mod joint;
pub mod plots;
mod sections;
mod story;
mod tables;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;

use crate::consistency::Thresholds;
use crate::diagnose::types::{model_name, Diagnosis, Rung};
use crate::format::{pm, with_sigma};
pub(crate) use joint::{draw_joint_pngs, render_joint_html, JointCoef, JointReportInput, JointRun};
use plots::{Figure, Kind};
use tables::*;

/// One identified parameter for the report's coefficient table.
#[derive(Clone, Debug)]
pub(crate) struct CoefRow {
    /// Parameter name (`DX0`, `GXxx-zz`, …).
    pub name: String,
    /// Unit (`deg/h`, …).
    pub unit: String,
    /// Estimate.
    pub value: f64,
    /// Its 1σ, noise only (the set-up as stated).
    pub sigma: f64,
    /// Its 1σ with the set-up's priors: the headline.
    pub sigma_total: f64,
    /// The source that adds most to it.
    pub dominant: String,
    /// Cramér–Rao bound (1σ).
    pub bound: f64,
    /// True value when the recording is simulated and its truth file was given.
    pub truth: Option<f64>,
    /// The alternatives it holds only on the absence of, with their reach in total 1σ.
    pub conditional_on: Vec<(String, f64)>,
}

/// Everything the report shows.
#[derive(Clone, Debug)]
pub(crate) struct ReportInput {
    /// Page title.
    pub title: String,
    /// Recording file name.
    pub recording: String,
    /// The recording's free-text description, if any.
    pub description: Option<String>,
    /// The diagnosis of every rung of the model ladder (first: the starting model; at least one).
    pub diagnoses: Vec<Diagnosis>,
    /// The ladder's rungs (same order as `diagnoses`).
    pub ladder: Vec<Rung>,
    /// The final model's identified parameters.
    pub coefficients: Vec<CoefRow>,
    /// Data-quality findings (shown first; empty for a clean recording).
    pub findings: Vec<crate::quality::Finding>,
    /// Why the result is not trusted (empty: trusted).
    pub untrusted: Vec<String>,
    /// What produced the page: the command line, and each effects file with its text.
    pub provenance: Provenance,
    /// `drift-markov`'s σ and τ fitted to the data, when it is in the final model.
    pub markov: Option<crate::identify::markov::MarkovFit>,
}

/// What produced a page (issue: a page must say which command, version, effects file and
/// options made it).
#[derive(Clone, Debug, Default)]
pub(crate) struct Provenance {
    /// The command line as given.
    pub command: String,
    /// Each `--effects` file: its path and its text.
    pub effects_files: Vec<(String, String)>,
}

/// A p-value as HTML text (`< 1e-300` must be escaped).
fn fmt_p(p: f64) -> String {
    esc(&plots::fmt_p(p))
}

/// Whether a Ljung–Box p-value passes as white: the threshold of the one definition of
/// consistent ([`Thresholds::whiteness_alpha`]).
fn white(p: f64) -> bool {
    p >= Thresholds::default().whiteness_alpha
}

/// Escapes text for HTML.
fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            _ => o.push(c),
        }
    }
    o
}

/// A number with 4 significant digits, in exponent form when very small or large.
fn num(v: f64) -> String {
    if !v.is_finite() {
        return "n/a".into();
    }
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}")
    }
}

/// Markdown-style `code` in the library's plain-text sentences (verdicts, reasons, findings),
/// escaped, with each pair of backticks rendered as `<code>`; an unpaired backtick stays text.
fn text(s: &str) -> String {
    let parts: Vec<&str> = s.split('`').collect();
    let mut o = String::with_capacity(s.len() + 16);
    for (k, part) in parts.iter().enumerate() {
        let paired = k % 2 == 1 && k + 1 < parts.len();
        match (k % 2 == 1, paired) {
            (true, true) => {
                let _ = write!(o, "<code>{}</code>", esc(part));
            }
            (true, false) => {
                o.push('`');
                o.push_str(&esc(part));
            }
            _ => o.push_str(&esc(part)),
        }
    }
    o
}

/// The page's style: a base font of 16 px (readable at 800 px), tables that scroll sideways in
/// their wrapper instead of being cut, numbers that never break across lines.
const STYLE: &str = r#"
body{font-family:"DejaVu Sans",Verdana,Arial,sans-serif;font-size:16px;max-width:1060px;margin:1.5em auto;padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em} h2{font-size:1.3em;border-bottom:2px solid #ccd;padding-bottom:.15em;margin-top:2em}
h3{font-size:1.08em;margin-top:1.4em}
.scroll{overflow-x:auto;max-width:100%;margin:.6em 0}
table{border-collapse:collapse;font-size:.95em} th,td{border:1px solid #ccd;padding:.22em .55em;text-align:right}
td{white-space:nowrap} td.l{white-space:normal;text-align:left} th.l{text-align:left}
.n{white-space:nowrap}
th{background:#eef}
.verdict{background:#f6f6ff;border-left:5px solid #557;padding:.6em 1em;margin:1em 0}
.headline{border:2px solid #557;border-left-width:10px;padding:.5em 1em;margin:1em 0;background:#f6f6ff}
.headline.untrusted{border-color:#b00;background:#fff4f4} .headline.trusted{border-color:#070;background:#f3fbf3}
.headline .state{font-size:1.5em;font-weight:bold;margin:.1em 0}
.headline .fit{font-size:1.15em;font-weight:bold;margin:.2em 0}
nav.toc{font-size:.95em;margin:1em 0} nav.toc ol{margin:.2em 0;padding-left:1.6em}
.bad{color:#b00;font-weight:bold} .ok{color:#070}
code{background:#eef;padding:0 .2em;border-radius:3px;font-size:.95em}
details>summary{cursor:pointer;color:#335}
figure{margin:1.2em 0} figcaption{font-size:.9em;color:#444;margin-top:.2em}
.svg svg{max-width:100%;height:auto}
.small{font-size:.9em;color:#555}
"#;

/// The page being written and the figures drawn for it.
pub(crate) struct Page<'a> {
    /// The HTML so far.
    pub(crate) h: String,
    /// What the page shows.
    pub(crate) input: &'a ReportInput,
    svgs: Vec<(Figure, String)>,
}

impl Page<'_> {
    /// Writes the figures of these kinds (those drawn for this input), in drawing order.
    pub(crate) fn figs(&mut self, kinds: &[Kind]) {
        for (f, s) in &self.svgs {
            if kinds.contains(&f.kind) {
                let _ = writeln!(
                    self.h,
                    "<figure><div class=\"svg\">{s}</div><figcaption>{}</figcaption></figure>",
                    esc(&caption(f))
                );
            }
        }
    }
}

/// Every table in a wrapper that scrolls sideways: at 800 px a wide table is scrolled, not cut.
fn wrap_tables(h: &str) -> String {
    h.replace("<table>", "<div class=\"scroll\"><table>")
        .replace("</table>", "</table></div>")
}

/// Renders the whole report as one HTML document.
pub(crate) fn render_html(input: &ReportInput) -> Result<String> {
    anyhow::ensure!(!input.diagnoses.is_empty(), "report: no diagnosis to show");
    let figs = plots::figures(input);
    let mut svgs = Vec::with_capacity(figs.len());
    for f in &figs {
        svgs.push((f.clone(), plots::svg(f, input)?));
    }
    let mut page = Page {
        h: String::new(),
        input,
        svgs,
    };
    sections::head(&mut page);
    story::verdict_block(&mut page.h, input);
    sections::toc(&mut page.h, input);
    sections::data_quality(&mut page.h, input);
    sections::summary(&mut page);
    sections::model_vs_measurements(&mut page);
    sections::where_it_fails(&mut page);
    sections::missing_effect(&mut page.h, input);
    sections::ladder(&mut page);
    sections::coefficients(&mut page.h, input);
    let _ = writeln!(page.h, "</body></html>");
    Ok(wrap_tables(&page.h))
}

fn caption(f: &Figure) -> String {
    let what = match f.kind {
        Kind::Story => "Where the model failed and what the ladder changed: mean NIS/3 per rung with the 99.9 % band the verdict uses; Ljung–Box p per rung against the whiteness level; the drift coefficients that moved most between the first and the final model, in units of the final 1σ.",
        Kind::Residual(_) => "Residual (measured − predicted) along the converged trajectory, m/s², with ±1 and ±3 × the noise floor estimated from the raw samples. Each failure window is shaded on the axis it belongs to.",
        Kind::Innovations(_) => "Filter innovations, m/s², with ±1σ and ±3σ bands from S.",
        Kind::Whitened(_) => "Whitened innovations (dimensionless): N(0,1) and white when the model holds.",
        Kind::Nis(_) => "NIS/3 on a log scale: per update and its rolling mean with the 95 % χ² band of that mean.",
        Kind::Acf(_) => "Autocorrelation of the whitened innovations per axis with the 95 % bound of a white sequence; stems beyond it in red.",
        Kind::Correlations(_) => "Correlation of the residual with candidate regressors (specific-force components, their products, time, temperature) with the 99 % bound.",
        Kind::Temperature(_) => "The recording's temperature, °C, with the failure windows shaded; where temperature drift stands among the candidates and its estimated size ± 1σ.",
        Kind::Ladder => "Residual RMS / noise floor per axis for each model of the ladder (log scale); 1 is the floor. Under the chart: the parameters each rung added, ± 1σ.",
        Kind::ResidualBeforeAfter => "Residual of the starting and of the final model averaged over windows of about an hour, m/s², with ±3σ of such a mean of noise at the floor: averaging takes the noise down, a missing effect's slow signature stays.",
        Kind::NisBeforeAfter => "Rolling NIS/3 of the starting and the final model (log scale).",
    };
    format!("{} [{}]", what, f.file)
}

/// The command line and the effects files that made the page, folded away.
fn provenance(h: &mut String, p: &Provenance) {
    if p.command.is_empty() {
        return;
    }
    let _ = writeln!(
        h,
        "<details class=\"small\"><summary>How this page was made</summary><p>Command: <code>{}</code> (driftid {})</p>",
        esc(&p.command),
        env!("CARGO_PKG_VERSION")
    );
    for (path, text) in &p.effects_files {
        let _ = writeln!(
            h,
            "<p>Effects file <code>{}</code>:</p><pre>{}</pre>",
            esc(path),
            esc(text)
        );
    }
    let _ = writeln!(h, "</details>");
}

/// Draws every figure as `DIR/NN-name.png` under a temporary name beside it, tagged as
/// driftid's ([`crate::output::tag_png`]); returns them uncommitted ([`crate::output::TempPath::commit`]
/// moves each into place; dropped, they vanish). Every PNG is checked first by `outputs` (not an
/// input, not another output, not a file driftid did not write, unless --force): nothing is
/// drawn when one is refused.
pub(crate) fn draw_pngs(
    input: &ReportInput,
    dir: &Path,
    outputs: &mut crate::output::Outputs,
) -> Result<Vec<crate::output::TempPath>> {
    anyhow::ensure!(!input.diagnoses.is_empty(), "report: no diagnosis to plot");
    let figures = plots::figures(input);
    write_pngs(&figures, dir, outputs, |_, f, p| plots::png(f, input, p))
}

/// [`draw_pngs`] of these figures, each drawn by `draw(index, figure, path)`.
fn write_pngs(
    figures: &[Figure],
    dir: &Path,
    outputs: &mut crate::output::Outputs,
    draw: impl Fn(usize, &Figure, &Path) -> Result<()>,
) -> Result<Vec<crate::output::TempPath>> {
    let paths: Vec<PathBuf> = figures
        .iter()
        .map(|f| dir.join(format!("{}.png", f.file)))
        .collect();
    crate::output::check_output_dir(dir, "--png")?;
    std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("--png {}: {e}", dir.display()))?;
    for p in &paths {
        outputs.check(p, "--png", crate::output::Made::Png)?;
    }
    let mut out = vec![];
    for (k, (f, p)) in figures.iter().zip(paths).enumerate() {
        // Drawn under a temporary name: never a partial PNG under the real one.
        let tmp = crate::output::TempPath::new(&p)?;
        draw(k, f, tmp.path()).map_err(|e| anyhow::anyhow!("{}: {e:#}", p.display()))?;
        let bytes =
            std::fs::read(tmp.path()).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        std::fs::write(tmp.path(), crate::output::tag_png(&bytes))
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        out.push(tmp);
    }
    Ok(out)
}
