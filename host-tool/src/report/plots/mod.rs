//! The report's plots, drawn once generically over the plotters backend: SVG (inline in the
//! HTML) and bitmap (the PNG files). Text is measured and rasterised with DejaVu Sans embedded in
//! the binary (registered with plotters' `ab_glyph` font layer), so no system font is needed.
//!
//! Long series are decimated to the minimum and maximum of each pixel column before drawing, and
//! y-ranges are chosen from robust quantiles (the first updates start from a wide prior and would
//! otherwise flatten everything else); values beyond the range are drawn at its edge.

use std::path::Path;
use std::sync::Once;

use anyhow::{anyhow, Result};
use plotters::coord::ranged1d::{Ranged, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;

use super::ReportInput;
use crate::diagnose::types::{model_name, rung_name, Diagnosis, Series};
use crate::stats::chi2_quantile;

mod acf;
mod correlations;
mod data;
mod ladder;
mod legend;
mod means;
mod panel;
mod series;
mod story;
mod temperature;
#[cfg(test)]
mod tests;

use acf::*;
use correlations::*;
use data::*;
use ladder::*;
use legend::*;
use means::*;
use panel::*;
use series::*;
use story::*;
use temperature::*;

/// Lowest NIS/3 a log axis shows (values below are drawn at the edge).
const NIS_LOG_FLOOR: f64 = 1e-3;
/// Pixel columns a long series is reduced to (min and max per column).
const COLS: usize = 900;
/// Figure width, px.
const WIDTH: u32 = 1000;
const FONT: &str = "sans-serif";
const AXES: [&str; 3] = ["x", "y", "z"];

/// Marks what is out of bounds: ACF stems beyond their bound, points beyond the frame.
const RED: RGBColor = RGBColor(200, 30, 30);
const LINE: RGBColor = RGBColor(30, 70, 150);
const BEFORE: RGBColor = RGBColor(215, 90, 60);
const AFTER: RGBColor = RGBColor(30, 70, 150);
const SHADE: RGBColor = RGBColor(255, 170, 170);
const BAND1: RGBColor = RGBColor(90, 170, 90);
const BAND3: RGBColor = RGBColor(190, 225, 190);
const AXIS_COLORS: [RGBColor; 3] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
];

/// Which plot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Kind {
    /// What changed along the ladder: NIS and whiteness per rung, the coefficients that moved.
    Story,
    /// Residual (measured − predicted) with the noise floor, per axis.
    Residual(usize),
    /// Innovations with ±1σ and ±3σ bands, per axis.
    Innovations(usize),
    /// Whitened innovations, per axis.
    Whitened(usize),
    /// NIS/3: raw and rolling mean with its χ² band.
    Nis(usize),
    /// Autocorrelation of the whitened innovations, per axis.
    Acf(usize),
    /// Correlation of the residual with candidate regressors.
    Correlations(usize),
    /// The recording's temperature with the temperature-drift candidate's standing.
    Temperature(usize),
    /// Residual RMS / floor per rung of the ladder.
    Ladder,
    /// Residual of the first and the last model, per axis.
    ResidualBeforeAfter,
    /// Rolling NIS/3 of the first and the last model.
    NisBeforeAfter,
}

/// One plot: what, its file stem and title, its size.
#[derive(Clone, Debug)]
pub(crate) struct Figure {
    /// What to draw.
    pub kind: Kind,
    /// File stem for the PNG (`01-measured-predicted`).
    pub file: String,
    /// Title drawn on top.
    pub title: String,
    /// Size, px.
    pub size: (u32, u32),
}

/// The figure for `kind`, titled for this input.
pub(crate) fn figure(kind: Kind, input: &ReportInput) -> Figure {
    let (stem, title, h) = spec(kind, input);
    let suffix = match kind {
        Kind::Residual(d)
        | Kind::Innovations(d)
        | Kind::Whitened(d)
        | Kind::Nis(d)
        | Kind::Acf(d)
        | Kind::Correlations(d)
        | Kind::Temperature(d) => {
            format!("-rung{d}")
        }
        _ => String::new(),
    };
    Figure {
        kind,
        file: format!("{stem}{suffix}"),
        title,
        size: (WIDTH, h),
    }
}

/// File stem, what it shows and height (px) of the figures that show one diagnosis alone, titled
/// "WHAT — model M" in the report and "WHAT — run R" in the joint report; `None` for the others.
fn one_diagnosis(kind: Kind) -> Option<(&'static str, &'static str, u32, usize)> {
    Some(match kind {
        Kind::Residual(d) => ("residual", "Residual (measured − predicted)", 640, d),
        Kind::Innovations(d) => (
            "innovations",
            "Filter innovations with ±1σ and ±3σ bands",
            640,
            d,
        ),
        Kind::Whitened(d) => (
            "whitened",
            "Whitened innovations (unit variance if the model holds)",
            640,
            d,
        ),
        Kind::Nis(d) => ("nis", "NIS/3 over time with its χ² band", 380, d),
        Kind::Acf(d) => ("acf", "Autocorrelation of the whitened innovations", 330, d),
        Kind::Correlations(d) => (
            "correlations",
            "Residual correlation with candidate regressors",
            380,
            d,
        ),
        _ => return None,
    })
}

/// File stem, title and height (px) of the figure of `kind`.
fn spec(kind: Kind, input: &ReportInput) -> (&'static str, String, u32) {
    let name = |d: usize| model_name(&input.diagnoses[d].model);
    let last = input.diagnoses.len() - 1;
    if let Some((stem, what, h, d)) = one_diagnosis(kind) {
        return (stem, format!("{what} — model {}", name(d)), h);
    }
    match kind {
        Kind::Story => (
            "what-changed",
            format!("What changed from {} to {}", name(0), name(last)),
            400,
        ),
        Kind::Temperature(d) => (
            "temperature",
            format!(
                "Platform temperature and the temperature drift — model {}",
                name(d)
            ),
            330 + notes_height(temperature_notes(input, d).len()),
        ),
        Kind::Ladder => (
            "ladder",
            "Model ladder: residual RMS / noise floor per rung (watch the error fall)".to_string(),
            400 + notes_height(ladder_estimates(&input.ladder).len()),
        ),
        Kind::ResidualBeforeAfter => (
            "residual-before-after",
            format!(
                "Residual averaged over windows, before ({}) and after ({})",
                name(0),
                name(last)
            ),
            640,
        ),
        Kind::NisBeforeAfter => (
            "nis-before-after",
            format!(
                "Rolling NIS/3 before ({}) and after ({})",
                name(0),
                name(last)
            ),
            360,
        ),
        // Shown by one diagnosis alone: returned above.
        _ => ("", String::new(), 0),
    }
}

/// A figure of the joint report that shows run `r` alone (`kind` one of [`one_diagnosis`]'s,
/// its index `r`), titled with the run's `label`: `None` for the other kinds.
pub(crate) fn run_figure(kind: Kind, label: &str) -> Option<Figure> {
    let (stem, what, h, r) = one_diagnosis(kind)?;
    Some(Figure {
        kind,
        file: format!("{stem}-run{}", r + 1),
        title: format!("{what} — run {label}"),
        size: (WIDTH, h),
    })
}

/// Every figure of the report, in the report's order.
pub(crate) fn figures(input: &ReportInput) -> Vec<Figure> {
    let last = input.diagnoses.len() - 1;
    let mut kinds = if last > 0 { vec![Kind::Story] } else { vec![] };
    kinds.extend([
        Kind::Residual(0),
        Kind::Innovations(0),
        Kind::Whitened(0),
        Kind::Nis(0),
        Kind::Acf(0),
        Kind::Correlations(0),
    ]);
    if shows_temperature(&input.diagnoses[0]) {
        kinds.push(Kind::Temperature(0));
    }
    kinds.push(Kind::Ladder);
    if last > 0 {
        kinds.extend([
            Kind::ResidualBeforeAfter,
            Kind::NisBeforeAfter,
            Kind::Acf(last),
        ]);
    }
    kinds
        .into_iter()
        .enumerate()
        .map(|(i, k)| {
            let mut f = figure(k, input);
            f.file = format!("{:02}-{}", i + 1, f.file);
            f
        })
        .collect()
}

fn ensure_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // Registration fails only for a malformed font file, which the crate does not ship.
        for family in ["sans-serif", "serif", "monospace"] {
            let _ =
                plotters::style::register_font(family, FontStyle::Normal, dejavu::sans::regular());
            let _ = plotters::style::register_font(family, FontStyle::Bold, dejavu::sans::bold());
        }
    });
}

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("drawing a plot: {e:?}")
}

/// The figure as an SVG document (for inlining in HTML).
pub(crate) fn svg(fig: &Figure, input: &ReportInput) -> Result<String> {
    svg_of(fig, Source::Report(input))
}

/// The figure as a PNG file.
pub(crate) fn png(fig: &Figure, input: &ReportInput, path: &Path) -> Result<()> {
    png_of(fig, Source::Report(input), path)
}

/// What a figure is drawn from: the report's whole input, or one diagnosis alone (a run of the
/// joint report, [`run_figure`]).
#[derive(Clone, Copy)]
pub(crate) enum Source<'a> {
    /// The single-run report's input.
    Report(&'a ReportInput),
    /// One diagnosis: the figures of [`one_diagnosis`]'s kinds.
    One(&'a Diagnosis),
}

/// The figure, drawn from `src`, as an SVG document.
pub(crate) fn svg_of(fig: &Figure, src: Source<'_>) -> Result<String> {
    ensure_font();
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, fig.size).into_drawing_area();
        draw(&root, fig, src)?;
        root.present().map_err(err)?;
    }
    Ok(out)
}

/// The figure, drawn from `src`, as a PNG file.
pub(crate) fn png_of(fig: &Figure, src: Source<'_>, path: &Path) -> Result<()> {
    ensure_font();
    let root = BitMapBackend::new(path, fig.size).into_drawing_area();
    draw(&root, fig, src)?;
    root.present().map_err(err)?;
    Ok(())
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    fig: &Figure,
    src: Source<'_>,
) -> Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let area = root
        .titled(&fig.title, (FONT, 18).into_font().style(FontStyle::Bold))
        .map_err(err)?;
    let input = match src {
        Source::One(d) => return draw_one(&area, fig.kind, d),
        Source::Report(input) => input,
    };
    if let Some((_, _, _, d)) = one_diagnosis(fig.kind) {
        return draw_one(&area, fig.kind, &input.diagnoses[d]);
    }
    let last = input.diagnoses.len() - 1;
    match fig.kind {
        Kind::Temperature(d) => temperature(&area, input, d),
        Kind::Ladder => ladder(&area, input),
        Kind::Story => what_changed(&area, input),
        Kind::ResidualBeforeAfter => {
            residual_means(&area, &input.diagnoses[0], &input.diagnoses[last])
        }
        Kind::NisBeforeAfter => nis(&area, &[&input.diagnoses[0], &input.diagnoses[last]], false),
        other => Err(anyhow!("{other:?}: not a figure of the whole report")),
    }
}

/// Draws a figure that shows one diagnosis alone ([`one_diagnosis`]'s kinds).
fn draw_one<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    kind: Kind,
    d: &Diagnosis,
) -> Result<()> {
    match kind {
        Kind::Residual(_) => residual(area, d),
        Kind::Innovations(_) => innovations(area, d),
        Kind::Whitened(_) => whitened(area, d),
        Kind::Nis(_) => nis(area, &[d], true),
        Kind::Acf(_) => acf(area, d),
        Kind::Correlations(_) => correlations(area, d),
        other => Err(anyhow!("{other:?}: not a figure of one diagnosis")),
    }
}

/// p-value for display ([`crate::format::p_value`]: one style everywhere).
pub(crate) fn fmt_p(p: f64) -> String {
    crate::format::p_value(p, f64::NAN)
}
