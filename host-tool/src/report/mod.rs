//! The report: one self-contained HTML page that tells the whole story of a recording — model
//! against data, where it fails, which effect is missing, the model ladder and the error falling,
//! and the identified coefficients with 1σ and the Cramér–Rao bound.
//!
//! Plots are inline SVG drawn by [`plots`] (plotters' SVG backend, text measured with an embedded
//! font); the page loads nothing from the network and needs no system font. The same figures can
//! be written as PNG files ([`draw_pngs`]).

pub mod plots;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;

use crate::consistency::Thresholds;
use crate::diagnose::types::{Diagnosis, Rung};
use crate::format::{pm, with_sigma};
use plots::{Figure, Kind};

/// One identified parameter for the report's coefficient table.
#[derive(Clone, Debug)]
pub struct CoefRow {
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
}

/// Everything the report shows.
#[derive(Clone, Debug)]
pub struct ReportInput {
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
}

/// What produced a page (issue: a page must say which command, version, effects file and
/// options made it).
#[derive(Clone, Debug, Default)]
pub struct Provenance {
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

fn model_name(m: &[String]) -> String {
    if m.is_empty() {
        "paper".into()
    } else {
        format!("paper + {}", m.join(" + "))
    }
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

const STYLE: &str = r#"
body{font-family:"DejaVu Sans",Verdana,Arial,sans-serif;max-width:1060px;margin:1.5em auto;padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em} h2{font-size:1.3em;border-bottom:2px solid #ccd;padding-bottom:.15em;margin-top:2em}
h3{font-size:1.08em;margin-top:1.4em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em} th,td{border:1px solid #ccd;padding:.22em .55em;text-align:right}
th{background:#eef} td.l,th.l{text-align:left}
.verdict{background:#f6f6ff;border-left:5px solid #557;padding:.6em 1em;margin:1em 0}
.bad{color:#b00;font-weight:bold} .ok{color:#070}
figure{margin:1.2em 0} figcaption{font-size:.88em;color:#444;margin-top:.2em}
.svg svg{max-width:100%;height:auto}
.small{font-size:.85em;color:#555}
"#;

/// Renders the whole report as one HTML document.
pub fn render_html(input: &ReportInput) -> Result<String> {
    anyhow::ensure!(!input.diagnoses.is_empty(), "report: no diagnosis to show");
    let figs = plots::figures(input);
    let mut svgs = Vec::with_capacity(figs.len());
    for f in &figs {
        svgs.push((f.clone(), plots::svg(f, input)?));
    }
    let fig = |kinds: &[Kind], h: &mut String| {
        for (f, s) in &svgs {
            if kinds.contains(&f.kind) {
                let _ = writeln!(
                    h,
                    "<figure><div class=\"svg\">{s}</div><figcaption>{}</figcaption></figure>",
                    esc(&caption(f))
                );
            }
        }
    };
    let first = &input.diagnoses[0];
    let last_i = input.diagnoses.len() - 1;
    let last = &input.diagnoses[last_i];
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">{}<title>{}</title><style>{STYLE}</style></head><body>\n",
        crate::output::HTML_GENERATOR,
        esc(&input.title)
    );
    let _ = writeln!(h, "<h1>{}</h1>", esc(&input.title));
    let _ = writeln!(
        h,
        "<p class=\"small\">Recording <b>{}</b>{}. Generated by driftid {}. Units: specific force m/s², drift deg/h, time h; every estimate with its 1σ.</p>",
        esc(&input.recording),
        input.description.as_deref().map(|d| format!(" — {}", esc(d))).unwrap_or_default(),
        env!("CARGO_PKG_VERSION")
    );
    provenance(&mut h, &input.provenance);

    // Data quality, first.
    let _ = writeln!(h, "<h2>Data quality</h2>");
    if input.findings.is_empty() {
        let _ = writeln!(h, "<p>No finding: every sample passed the screening and the recording agrees with its metadata and with physics.</p>");
    } else {
        let _ = writeln!(h, "<ul>");
        for f in &input.findings {
            let _ = writeln!(h, "<li>{}</li>", esc(&f.line()));
        }
        let _ = writeln!(h, "</ul>");
    }
    if !input.untrusted.is_empty() {
        let _ = writeln!(h, "<div class=\"verdict\"><b>NOT TRUSTED:</b> the numbers below are computed but the tool does not trust them:<ul>");
        for r in &input.untrusted {
            let _ = writeln!(h, "<li>{}</li>", esc(r));
        }
        let _ = writeln!(h, "</ul></div>");
    }

    // Summary
    let _ = writeln!(h, "<h2>Summary</h2>");
    let _ = writeln!(
        h,
        "<div class=\"verdict\"><b>Starting model ({}):</b> {}</div>",
        esc(&model_name(&first.model)),
        esc(&first.verdict)
    );
    if last_i > 0 {
        let _ = writeln!(
            h,
            "<div class=\"verdict\"><b>Final model ({}):</b> {}</div>",
            esc(&model_name(&last.model)),
            esc(&last.verdict)
        );
    }
    fit_table(&mut h, &input.diagnoses);

    // 1. Model vs measurements
    let _ = writeln!(
        h,
        "<h2>1. The model against the measurements (model: {})</h2>",
        esc(&model_name(&first.model))
    );
    let _ = writeln!(
        h,
        "<p>The measured specific force (means over each filter period) and the model's prediction along the converged trajectory; the residual against the noise floor estimated from the raw samples themselves; the filter's innovations with their ±1σ/±3σ bands; the whitened innovations, unit-variance white noise when the model holds; and NIS/3, whose mean must fall in its χ² band. Shaded intervals are the failure windows.</p>"
    );
    fig(
        &[
            Kind::MeasuredPredicted(0),
            Kind::Residual(0),
            Kind::Innovations(0),
            Kind::Whitened(0),
            Kind::Nis(0),
        ],
        &mut h,
    );

    // 2. Where it fails
    let _ = writeln!(h, "<h2>2. Where it fails</h2>");
    let w = &first.whiteness;
    let _ = writeln!(
        h,
        "<p>Whiteness of the whitened innovations: Ljung–Box Q = {:.1} on {:.0} degrees of freedom, p = {} {}.</p>",
        w.ljung_box_q,
        w.dof,
        fmt_p(w.p_value),
        if white(w.p_value) { "<span class=\"ok\">(white)</span>" } else { "<span class=\"bad\">(not white: the model misses a systematic effect)</span>" }
    );
    if first.failures.is_empty() {
        let _ = writeln!(
            h,
            "<p>No time window where the residuals leave their band.</p>"
        );
    } else {
        let _ = writeln!(
            h,
            "<table><tr><th>from, h</th><th>to, h</th><th>mean NIS/3</th><th>worst axis</th></tr>"
        );
        for f in first.failures.iter().take(20) {
            let _ = writeln!(
                h,
                "<tr><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td><td>{}</td></tr>",
                f.start_h, f.end_h, f.nis_mean, f.worst_axis
            );
        }
        if first.failures.len() > 20 {
            let _ = writeln!(
                h,
                "<tr><td class=\"l\" colspan=\"4\">… and {} more windows</td></tr>",
                first.failures.len() - 20
            );
        }
        let _ = writeln!(h, "</table>");
    }
    fig(
        &[Kind::Acf(0), Kind::Correlations(0), Kind::Temperature(0)],
        &mut h,
    );
    let mut strong: Vec<_> = first
        .correlations
        .iter()
        .flat_map(|c| (0..3).map(move |a| (c, a)))
        .filter(|(c, a)| c.corr[*a].abs() > c.bound99)
        .collect();
    strong.sort_by(|x, y| y.0.corr[y.1].abs().total_cmp(&x.0.corr[x.1].abs()));
    if !strong.is_empty() {
        let _ = writeln!(h, "<p>Residual correlations beyond their 99 % bound (strongest first):</p><table><tr><th class=\"l\">regressor</th><th>axis</th><th>correlation</th><th>99 % bound</th></tr>");
        for (c, a) in strong.iter().take(12) {
            let _ = writeln!(
                h,
                "<tr><td class=\"l\">{}</td><td>{}</td><td>{:+.3}</td><td>±{:.3}</td></tr>",
                esc(&c.regressor),
                ["x", "y", "z"][*a],
                c.corr[*a],
                c.bound99
            );
        }
        let _ = writeln!(h, "</table>");
    }

    // 3. Which effect is missing
    let _ = writeln!(h, "<h2>3. Which physical effect is missing</h2>");
    let _ = writeln!(
        h,
        "<p>Each catalog effect not in the model is scored by a Lagrange-multiplier (score) test from the current model's innovations and their sensitivity to the effect's parameters (one replay, no re-estimation). p is adjusted for the number of candidates (Holm). The estimated size comes with its 1σ and the smallest size this run could have detected (90 % power at the 1 % level).</p>"
    );
    ranking_table(&mut h, first);
    for c in &first.confounding {
        let _ = writeln!(
            h,
            "<p>{}<b>{}</b> and <b>{}</b> leave nearly the same signature on this run (canonical correlation {:.3}); their score tests' −2 ln p differ by {:.1}{}. To separate them: {}.</p>",
            if c.separated { "" } else { "<span class=\"bad\">Not separated:</span> " },
            esc(&c.a),
            esc(&c.b),
            c.canonical_correlation,
            c.statistic_gap,
            if c.separated { ", so the data still prefer the first" } else { ", too small to prefer one: both are shown" },
            esc(&c.separate_by)
        );
    }

    // 4. The ladder
    let _ = writeln!(
        h,
        "<h2>4. Add it and watch the error fall: the model ladder</h2>"
    );
    ladder_table(&mut h, &input.ladder);
    fig(
        &[
            Kind::Ladder,
            Kind::ResidualBeforeAfter,
            Kind::NisBeforeAfter,
        ],
        &mut h,
    );
    if last_i > 0 {
        fig(&[Kind::Acf(last_i)], &mut h);
        let _ = writeln!(
            h,
            "<h3>Candidates left after the final model ({})</h3>",
            esc(&model_name(&last.model))
        );
        ranking_table(&mut h, last);
    }
    movement_table(&mut h, &input.ladder);

    // 5. Coefficients
    let _ = writeln!(
        h,
        "<h2>5. Identified coefficients (final model: {})</h2>",
        esc(&model_name(&last.model))
    );
    coefficient_table(&mut h, &input.coefficients);
    let _ = writeln!(
        h,
        "<p class=\"small\">Converged identification: a forward EKF pass from a wide prior, then iterated Rauch–Tung–Striebel smoothing (Gauss–Newton over the whole record); the 1σ is the smoother's, the bound is the Cramér–Rao bound from the Fisher information of the measurement sensitivities and the gyro random drift.</p>"
    );
    let _ = writeln!(h, "</body></html>");
    Ok(h)
}

fn caption(f: &Figure) -> String {
    let what = match f.kind {
        Kind::MeasuredPredicted(_) => "Measured (window means) and predicted specific force per axis, m/s².",
        Kind::Residual(_) => "Residual along the converged trajectory, m/s², with ±1σ of the noise floor estimated from the raw samples.",
        Kind::Innovations(_) => "Filter innovations, m/s², with ±1σ and ±3σ bands from S.",
        Kind::Whitened(_) => "Whitened innovations (dimensionless): N(0,1) and white when the model holds.",
        Kind::Nis(_) => "NIS/3 on a log scale: per update and its rolling mean with the 95 % χ² band of that mean.",
        Kind::Acf(_) => "Autocorrelation of the whitened innovations per axis with the 95 % bound of a white sequence.",
        Kind::Correlations(_) => "Correlation of the residual with candidate regressors (specific-force components, their products, time, temperature) with the 99 % bound.",
        Kind::Temperature(_) => "The recording's temperature, °C, with the failure windows shaded; where temperature drift stands among the candidates and its estimated size ± 1σ.",
        Kind::Ladder => "Residual RMS / noise floor per axis for each model of the ladder (log scale); 1 is the floor. Under the chart: the parameters each rung added, ± 1σ.",
        Kind::ResidualBeforeAfter => "Residual of the starting model and of the final model, m/s².",
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

fn fit_table(h: &mut String, ds: &[Diagnosis]) {
    let _ = writeln!(
        h,
        "<table><tr><th class=\"l\">model</th><th>RMS/floor x</th><th>y</th><th>z</th><th>mean NIS/3</th><th>{:.1} % band</th><th>Ljung–Box p</th><th>failure windows</th><th>consistent</th></tr>",
        100.0 * Thresholds::default().nis_band_prob
    );
    for d in ds {
        // Coloured by the one definition of consistent (crate::consistency).
        let band = d.consistency.nis_band;
        let in_band = d.nis_mean >= band[0] && d.nis_mean <= band[1];
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">{}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td class=\"{}\">{:.3}</td><td>[{:.3}, {:.3}]</td><td class=\"{}\">{}</td><td>{}</td><td class=\"{}\">{}</td></tr>",
            esc(&model_name(&d.model)),
            d.residual_rms_over_floor[0],
            d.residual_rms_over_floor[1],
            d.residual_rms_over_floor[2],
            if in_band { "ok" } else { "bad" },
            d.nis_mean,
            band[0],
            band[1],
            if white(d.whiteness.p_value) { "ok" } else { "bad" },
            fmt_p(d.whiteness.p_value),
            d.failures.len(),
            if d.consistency.is_consistent() { "ok" } else { "bad" },
            if d.consistency.is_consistent() { "yes" } else { "no" }
        );
    }
    let _ = writeln!(h, "</table>");
    if let Some(d) = ds.first() {
        let _ = writeln!(
            h,
            "<p class=\"small\">Noise floor of one filter-period mean (from raw-sample differences): x {:.3e}, y {:.3e}, z {:.3e} m/s².</p>",
            d.floor_mps2[0], d.floor_mps2[1], d.floor_mps2[2]
        );
    }
}

fn ranking_table(h: &mut String, d: &Diagnosis) {
    if d.ranking.is_empty() {
        let _ = writeln!(h, "<p>No candidate left to test.</p>");
        return;
    }
    let _ = writeln!(
        h,
        "<table><tr><th>#</th><th class=\"l\">effect</th><th>statistic</th><th>dof</th><th>p</th><th>p (Holm)</th><th class=\"l\">estimated size ± 1σ (detectable ≥)</th><th>evidence gain (refit)</th><th>RMS/floor after refit (x, y, z)</th><th class=\"l\">physics</th></tr>"
    );
    for (i, c) in d.ranking.iter().enumerate() {
        if let Some(why) = &c.untestable {
            let _ = writeln!(h, "<tr><td>{}</td><td class=\"l\">{}</td><td colspan=\"7\" class=\"l\">not testable: {}</td><td class=\"l small\">{}</td></tr>", i + 1, esc(&c.effect), esc(why), esc(&c.about));
            continue;
        }
        let mut sizes = String::new();
        for p in c.params.iter().take(6) {
            let _ = write!(
                sizes,
                "{} = {} {} (≥ {})<br>",
                esc(&p.name),
                esc(&crate::format::pm(p.value, p.sigma)),
                esc(&p.unit),
                num(p.min_detectable)
            );
        }
        if c.params.len() > 6 {
            let _ = write!(sizes, "… {} more", c.params.len() - 6);
        }
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td class=\"l\"><b>{}</b></td><td>{:.1}</td><td>{:.0}</td><td>{}</td><td class=\"{}\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{}</td><td class=\"l small\">{}</td></tr>",
            i + 1,
            esc(&c.effect),
            c.statistic,
            c.dof,
            esc(&crate::format::p_value(c.p_value, c.ln_p_value)),
            if c.p_adjusted < 0.01 { "bad" } else { "ok" },
            esc(&crate::format::p_value(c.p_adjusted, c.ln_p_adjusted)),
            sizes,
            c.refit.as_ref().map(|r| format!("{:+.1}", r.evidence_gain)).unwrap_or_else(|| "—".into()),
            c.refit
                .as_ref()
                .map(|r| format!("{:.3}, {:.3}, {:.3}", r.rms_over_floor[0], r.rms_over_floor[1], r.rms_over_floor[2]))
                .unwrap_or_else(|| "not refitted".into()),
            esc(&c.about)
        );
    }
    let _ = writeln!(h, "</table>");
}

fn ladder_table(h: &mut String, rungs: &[Rung]) {
    let _ = writeln!(
        h,
        "<table><tr><th>rung</th><th class=\"l\">model</th><th>RMS/floor x</th><th>y</th><th>z</th><th>mean NIS/3</th><th>Ljung–Box p</th><th class=\"l\">next: added effect (p)</th></tr>"
    );
    for (i, r) in rungs.iter().enumerate() {
        let next = match &r.next {
            Some((e, p)) => format!("{} (p = {})", esc(e), fmt_p(*p)),
            None => "— (stop: no candidate significant)".into(),
        };
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td class=\"l\">{}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{}</td><td class=\"l\">{}</td></tr>",
            i,
            esc(&model_name(&r.model)),
            r.residual_rms_over_floor[0],
            r.residual_rms_over_floor[1],
            r.residual_rms_over_floor[2],
            r.nis_mean,
            fmt_p(r.whiteness_p),
            next
        );
    }
    let _ = writeln!(h, "</table>");
}

/// How the 12 drift coefficients moved from rung to rung.
fn movement_table(h: &mut String, rungs: &[Rung]) {
    if rungs.len() < 2 {
        return;
    }
    let _ = writeln!(
        h,
        "<h3>How the drift coefficients moved along the ladder (value ± 1σ)</h3>"
    );
    let _ = write!(h, "<table><tr><th class=\"l\">coefficient</th>");
    for (i, r) in rungs.iter().enumerate() {
        let _ = write!(h, "<th>rung {i}: {}</th>", esc(&model_name(&r.model)));
    }
    let _ = writeln!(h, "<th>change / 1σ</th></tr>");
    let n = rungs[0].coefficients.len();
    for k in 0..n {
        let (name, v0, _) = &rungs[0].coefficients[k];
        let _ = write!(h, "<tr><td class=\"l\">{}</td>", esc(name));
        for r in rungs {
            match r.coefficients.get(k) {
                Some((_, v, s)) => {
                    let _ = write!(h, "<td>{}</td>", esc(&pm(*v, *s)));
                }
                None => {
                    let _ = write!(h, "<td>n/a</td>");
                }
            }
        }
        let (_, vl, sl) = rungs[rungs.len() - 1]
            .coefficients
            .get(k)
            .cloned()
            .unwrap_or_default();
        let _ = writeln!(h, "<td>{:+.1}</td></tr>", (vl - v0) / sl);
    }
    let _ = writeln!(
        h,
        "</table><p class=\"small\">Units: D·0 deg/h, D·x/y/z deg/h/(m/s²).</p>"
    );
}

fn coefficient_table(h: &mut String, rows: &[CoefRow]) {
    let truth = rows.iter().any(|r| r.truth.is_some());
    let _ = write!(h, "<table><tr><th class=\"l\">parameter</th><th class=\"l\">unit</th><th>estimate ± 1σ total</th><th>noise 1σ</th><th>bound (CRB 1σ)</th><th>noise 1σ / bound</th><th>total / noise</th><th class=\"l\">most from</th>");
    if truth {
        let _ = write!(h, "<th>truth</th><th>error</th><th>error / 1σ total</th>");
    }
    let _ = writeln!(h, "</tr>");
    for r in rows {
        let _ = write!(
            h,
            "<tr><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{:.2e}</td><td>{:.2e}</td><td>{:.2}</td><td>{:.2}</td><td class=\"l\">{}</td>",
            esc(&r.name),
            esc(&r.unit),
            esc(&pm(r.value, r.sigma_total)),
            r.sigma,
            r.bound,
            r.sigma / r.bound,
            r.sigma_total / r.sigma,
            esc(&r.dominant)
        );
        if truth {
            match r.truth {
                Some(t) => {
                    let e = r.value - t;
                    let z = e / r.sigma_total;
                    let _ = write!(
                        h,
                        "<td>{}</td><td>{}</td><td class=\"{}\">{:+.2}</td>",
                        num(t),
                        with_sigma(e, r.sigma_total),
                        if z.abs() > 3.0 { "bad" } else { "ok" },
                        z
                    );
                }
                None => {
                    let _ = write!(h, "<td>—</td><td>—</td><td>—</td>");
                }
            }
        }
        let _ = writeln!(h, "</tr>");
    }
    let _ = writeln!(h, "</table>");
}

/// Draws every figure as `DIR/NN-name.png` under a temporary name beside it, tagged as
/// driftid's ([`crate::output::tag_png`]); returns them uncommitted ([`crate::output::TempPath::commit`]
/// moves each into place; dropped, they vanish). Every PNG is checked first by `outputs` (not an
/// input, not another output, not a file driftid did not write, unless --force): nothing is
/// drawn when one is refused.
pub fn draw_pngs(
    input: &ReportInput,
    dir: &Path,
    outputs: &mut crate::output::Outputs,
) -> Result<Vec<crate::output::TempPath>> {
    anyhow::ensure!(!input.diagnoses.is_empty(), "report: no diagnosis to plot");
    let figures = plots::figures(input);
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
    for (f, p) in figures.iter().zip(paths) {
        // Drawn under a temporary name: never a partial PNG under the real one.
        let tmp = crate::output::TempPath::new(&p)?;
        plots::png(f, input, tmp.path()).map_err(|e| anyhow::anyhow!("{}: {e:#}", p.display()))?;
        let bytes =
            std::fs::read(tmp.path()).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        std::fs::write(tmp.path(), crate::output::tag_png(&bytes))
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        out.push(tmp);
    }
    Ok(out)
}
