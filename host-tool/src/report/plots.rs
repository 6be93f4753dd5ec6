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
use crate::diagnose::types::{Diagnosis, Series};
use crate::stats::chi2_quantile;

/// Lowest NIS/3 a log axis shows (values below are drawn at the edge).
const NIS_LOG_FLOOR: f64 = 1e-3;
/// Pixel columns a long series is reduced to (min and max per column).
const COLS: usize = 900;
/// Figure width, px.
const WIDTH: u32 = 1000;
const FONT: &str = "sans-serif";
const AXES: [&str; 3] = ["x", "y", "z"];

const MEASURED: RGBColor = RGBColor(120, 160, 215);
const PREDICTED: RGBColor = RGBColor(200, 30, 30);
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
pub enum Kind {
    /// Measured and predicted specific force, per axis, of diagnosis `d`.
    MeasuredPredicted(usize),
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
pub struct Figure {
    /// What to draw.
    pub kind: Kind,
    /// File stem for the PNG (`01-measured-predicted`).
    pub file: String,
    /// Title drawn on top.
    pub title: String,
    /// Size, px.
    pub size: (u32, u32),
}

fn model_name(d: &Diagnosis) -> String {
    if d.model.is_empty() {
        "paper".into()
    } else {
        format!("paper + {}", d.model.join(" + "))
    }
}

/// The figure for `kind`, titled for this input.
pub fn figure(kind: Kind, input: &ReportInput) -> Figure {
    let name = |d: usize| model_name(&input.diagnoses[d]);
    let last = input.diagnoses.len() - 1;
    let (stem, title, h) = match kind {
        Kind::MeasuredPredicted(d) => (
            "measured-predicted",
            format!("Measured and predicted specific force — model {}", name(d)),
            640,
        ),
        Kind::Residual(d) => (
            "residual",
            format!("Residual (measured − predicted) — model {}", name(d)),
            640,
        ),
        Kind::Innovations(d) => (
            "innovations",
            format!(
                "Filter innovations with ±1σ and ±3σ bands — model {}",
                name(d)
            ),
            640,
        ),
        Kind::Whitened(d) => (
            "whitened",
            format!(
                "Whitened innovations (unit variance if the model holds) — model {}",
                name(d)
            ),
            640,
        ),
        Kind::Nis(d) => (
            "nis",
            format!("NIS/3 over time with its χ² band — model {}", name(d)),
            380,
        ),
        Kind::Acf(d) => (
            "acf",
            format!(
                "Autocorrelation of the whitened innovations — model {}",
                name(d)
            ),
            330,
        ),
        Kind::Correlations(d) => (
            "correlations",
            format!(
                "Residual correlation with candidate regressors — model {}",
                name(d)
            ),
            380,
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
            format!("Residual before ({}) and after ({})", name(0), name(last)),
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
    };
    let suffix = match kind {
        Kind::MeasuredPredicted(d)
        | Kind::Residual(d)
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

/// Every figure of the report, in the report's order.
pub fn figures(input: &ReportInput) -> Vec<Figure> {
    let last = input.diagnoses.len() - 1;
    let mut kinds = vec![
        Kind::MeasuredPredicted(0),
        Kind::Residual(0),
        Kind::Innovations(0),
        Kind::Whitened(0),
        Kind::Nis(0),
        Kind::Acf(0),
        Kind::Correlations(0),
    ];
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
pub fn svg(fig: &Figure, input: &ReportInput) -> Result<String> {
    ensure_font();
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, fig.size).into_drawing_area();
        draw(&root, fig, input)?;
        root.present().map_err(err)?;
    }
    Ok(out)
}

/// The figure as a PNG file.
pub fn png(fig: &Figure, input: &ReportInput, path: &Path) -> Result<()> {
    ensure_font();
    let root = BitMapBackend::new(path, fig.size).into_drawing_area();
    draw(&root, fig, input)?;
    root.present().map_err(err)?;
    Ok(())
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    fig: &Figure,
    input: &ReportInput,
) -> Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let area = root
        .titled(&fig.title, (FONT, 18).into_font().style(FontStyle::Bold))
        .map_err(err)?;
    let last = input.diagnoses.len() - 1;
    match fig.kind {
        Kind::MeasuredPredicted(d) => measured_predicted(&area, &input.diagnoses[d]),
        Kind::Residual(d) => residual(&area, &input.diagnoses[d], None),
        Kind::Innovations(d) => innovations(&area, &input.diagnoses[d]),
        Kind::Whitened(d) => whitened(&area, &input.diagnoses[d]),
        Kind::Nis(d) => nis(&area, &[&input.diagnoses[d]], true),
        Kind::Acf(d) => acf(&area, &input.diagnoses[d]),
        Kind::Correlations(d) => correlations(&area, &input.diagnoses[d]),
        Kind::Temperature(d) => temperature(&area, input, d),
        Kind::Ladder => ladder(&area, input),
        Kind::ResidualBeforeAfter => {
            residual(&area, &input.diagnoses[0], Some(&input.diagnoses[last]))
        }
        Kind::NisBeforeAfter => nis(&area, &[&input.diagnoses[0], &input.diagnoses[last]], false),
    }
}

// ---------------------------------------------------------------------------------------------
// Data helpers

/// Reduces a series to the minimum and maximum of each of `cols` columns over `x`, in time order.
/// Non-finite values are skipped.
pub fn decimate(
    t: &[f64],
    v: impl Fn(usize) -> f64,
    x: (f64, f64),
    cols: usize,
) -> Vec<(f64, f64)> {
    let span = (x.1 - x.0).max(f64::MIN_POSITIVE);
    let mut out = Vec::with_capacity(2 * cols + 2);
    let mut cur: Option<(usize, usize, usize)> = None; // (column, index of min, index of max)
    let flush = |out: &mut Vec<(f64, f64)>, c: Option<(usize, usize, usize)>| {
        if let Some((_, a, b)) = c {
            let (i, j) = if a <= b { (a, b) } else { (b, a) };
            out.push((t[i], v(i)));
            if j != i {
                out.push((t[j], v(j)));
            }
        }
    };
    for (i, &ti) in t.iter().enumerate() {
        let y = v(i);
        if !(y.is_finite() && ti.is_finite()) {
            continue;
        }
        let c = (((ti - x.0) / span * cols as f64).floor().max(0.0) as usize).min(cols - 1);
        match cur {
            Some((cc, a, b)) if cc == c => {
                let a = if y < v(a) { i } else { a };
                let b = if y > v(b) { i } else { b };
                cur = Some((c, a, b));
            }
            _ => {
                flush(&mut out, cur);
                cur = Some((c, i, i));
            }
        }
    }
    flush(&mut out, cur);
    out
}

/// The `q` quantile of the finite values (0 when there are none).
pub fn quantile(vals: impl Iterator<Item = f64>, q: f64) -> f64 {
    let mut v: Vec<f64> = vals.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let k = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    v[k]
}

fn x_range(t: &[f64]) -> (f64, f64) {
    let a = t
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .fold(f64::INFINITY, f64::min);
    let b = t
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .fold(f64::NEG_INFINITY, f64::max);
    if !(a.is_finite() && b.is_finite()) {
        return (0.0, 1.0);
    }
    if b > a {
        (a, b)
    } else {
        (a, a + 1.0)
    }
}

/// Median update interval, h.
pub fn period_h(t: &[f64]) -> f64 {
    let d: Vec<f64> = t
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .collect();
    let p = quantile(d.into_iter(), 0.5);
    if p > 0.0 {
        p
    } else {
        1.0 / 60.0
    }
}

/// Rolling (centred) mean of NIS/3 over about one hour (a tenth of the run when shorter than
/// ten hours): the points, the window length in updates and its 95 % band.
pub fn rolling_nis(s: &Series) -> (Vec<(f64, f64)>, usize, [f64; 2]) {
    let n = s.nis.len().min(s.t_h.len());
    let dt = period_h(&s.t_h);
    let run = x_range(&s.t_h);
    let hours = if run.1 - run.0 >= 10.0 {
        1.0
    } else {
        ((run.1 - run.0) / 10.0).max(dt)
    };
    let w = ((hours / dt).round() as usize).clamp(1, n.max(1));
    let mut out = vec![];
    if n >= w && w > 0 {
        let mut sum: f64 = s.nis[..w]
            .iter()
            .map(|x| if x.is_finite() { *x } else { 0.0 })
            .sum();
        for i in 0..=(n - w) {
            if i > 0 {
                let add = s.nis[i + w - 1];
                let sub = s.nis[i - 1];
                sum += if add.is_finite() { add } else { 0.0 }
                    - if sub.is_finite() { sub } else { 0.0 };
            }
            out.push((s.t_h[i + w / 2], sum / (3.0 * w as f64)));
        }
    }
    let k = 3.0 * w as f64;
    (
        out,
        w,
        [chi2_quantile(0.025, k) / k, chi2_quantile(0.975, k) / k],
    )
}

/// A power of ten that brings `max_abs` to 1..1000, and its label (`10⁻⁴ `); none for ordinary
/// magnitudes.
fn scale(max_abs: f64) -> (f64, String) {
    if !(max_abs.is_finite() && max_abs > 0.0) {
        return (1.0, String::new());
    }
    let e = max_abs.log10().floor() as i32;
    if (-1..=3).contains(&e) {
        return (1.0, String::new());
    }
    (10f64.powi(-e), format!("10{} ", superscript(e)))
}

fn superscript(e: i32) -> String {
    e.to_string()
        .chars()
        .map(|c| match c {
            '-' => '⁻',
            '0' => '⁰',
            '1' => '¹',
            '2' => '²',
            '3' => '³',
            '4' => '⁴',
            '5' => '⁵',
            '6' => '⁶',
            '7' => '⁷',
            '8' => '⁸',
            _ => '⁹',
        })
        .collect()
}

/// A tick label: up to three decimals, trailing zeros dropped.
fn tick(v: f64) -> String {
    // Axis ticks computed as sums land on ±1e-17 instead of 0.
    if v.abs() < 1e-12 {
        return "0".into();
    }
    if v.abs() >= 1e5 || v.abs() < 1e-3 {
        return format!("{v:.1e}");
    }
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

// ---------------------------------------------------------------------------------------------
// Legends: drawn in a strip reserved to the right of the plotting area, never over the data

/// Width of the legend strip to the right of every chart, px.
const LEGEND_W: i32 = 200;
/// Characters per legend line before it wraps.
const LEGEND_WRAP: usize = 25;

/// How a legend entry is drawn.
#[derive(Clone, Copy)]
enum Mark {
    /// A line in this style (dashed or solid).
    Line(ShapeStyle, bool),
    /// A filled swatch.
    Fill(RGBAColor),
}

/// One legend entry.
struct Entry {
    label: String,
    mark: Mark,
}

fn entry(label: impl Into<String>, mark: Mark) -> Entry {
    Entry {
        label: label.into(),
        mark,
    }
}

/// Splits `area` into the plotting part and the legend strip on its right.
fn with_legend_strip<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
) -> (DrawingArea<DB, Shift>, DrawingArea<DB, Shift>) {
    let w = area.dim_in_pixel().0 as i32;
    area.split_horizontally((w - LEGEND_W).max(w / 2))
}

/// `label` broken into lines of at most [`LEGEND_WRAP`] characters at spaces.
fn wrap(label: &str) -> Vec<String> {
    let mut lines: Vec<String> = vec![];
    for word in label.split(' ') {
        match lines.last_mut() {
            Some(l) if l.chars().count() + 1 + word.chars().count() <= LEGEND_WRAP => {
                l.push(' ');
                l.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
}

/// Draws the legend entries top-down in `strip` (the area beside the chart).
fn legend_strip<DB: DrawingBackend>(
    strip: &DrawingArea<DB, Shift>,
    entries: &[Entry],
) -> Result<()> {
    let mut y = 10;
    for e in entries {
        let (x0, x1, ym) = (6, 26, y + 7);
        match e.mark {
            Mark::Line(style, true) => strip.draw(&DashedPathElement::new(
                vec![(x0, ym), (x1, ym)],
                5,
                3,
                style.stroke_width(2),
            )),
            Mark::Line(style, false) => strip.draw(&PathElement::new(
                vec![(x0, ym), (x1, ym)],
                style.stroke_width(2),
            )),
            Mark::Fill(c) => strip.draw(&Rectangle::new([(x0, ym - 5), (x1, ym + 5)], c.filled())),
        }
        .map_err(err)?;
        for line in wrap(&e.label) {
            strip
                .draw(&Text::new(line, (x1 + 6, y), (FONT, 12)))
                .map_err(err)?;
            y += 15;
        }
        y += 5;
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// A time panel

struct Line {
    label: Option<String>,
    color: RGBColor,
    width: u32,
    dashed: bool,
    pts: Vec<(f64, f64)>,
}

/// A band ±`upper(t)` about zero.
struct Band {
    label: Option<String>,
    color: RGBColor,
    upper: Vec<(f64, f64)>,
}

#[derive(Default)]
struct Panel {
    caption: Option<String>,
    x_desc: Option<String>,
    y_desc: String,
    y: (f64, f64),
    /// A logarithmic y axis (`y` must then be positive).
    log_y: bool,
    lines: Vec<Line>,
    bands: Vec<Band>,
    /// Constant bands (lo, hi, colour, label).
    hbands: Vec<(f64, f64, RGBColor, Option<String>)>,
    /// Horizontal reference lines (value, colour, label).
    hlines: Vec<(f64, RGBColor, Option<String>)>,
    /// Shaded time intervals (failure windows).
    shade: Vec<(f64, f64)>,
    legend: bool,
}

fn clamp_pts(p: &[(f64, f64)], y: (f64, f64)) -> Vec<(f64, f64)> {
    p.iter().map(|&(t, v)| (t, v.clamp(y.0, y.1))).collect()
}

/// One time panel: the chart on the left, its legend (when `p.legend`) in the strip on the right;
/// every panel keeps the strip so stacked panels share their time axis.
fn time_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    x: (f64, f64),
    p: &Panel,
) -> Result<()> {
    let (plot, strip) = with_legend_strip(area);
    let (y0, y1) = p.y;
    let mut b = ChartBuilder::on(&plot);
    b.margin_left(8)
        .margin_right(8)
        .margin_top(4)
        .margin_bottom(4);
    b.x_label_area_size(if p.x_desc.is_some() { 44 } else { 22 })
        .y_label_area_size(78);
    if let Some(c) = &p.caption {
        b.caption(c, (FONT, 14));
    }
    let entries = if p.log_y {
        let y = (y0..y1).log_scale().with_key_points(log_ticks(y0, y1));
        let mut chart = b.build_cartesian_2d(x.0..x.1, y).map_err(err)?;
        panel_body(&mut chart, x, p)?
    } else {
        let mut chart = b.build_cartesian_2d(x.0..x.1, y0..y1).map_err(err)?;
        panel_body(&mut chart, x, p)?
    };
    if p.legend {
        legend_strip(&strip, &entries)?;
    }
    Ok(())
}

/// Ticks of a log axis over `[lo, hi]`: 1, 2, 5 × powers of ten, or 1…9 × when that gives fewer
/// than three (plotters' own log ticks are powers of ten only: one label over one decade).
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let ticks = log_ticks_with(lo, hi, &[1.0, 2.0, 5.0]);
    if ticks.len() >= 3 {
        return ticks;
    }
    log_ticks_with(lo, hi, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
}

/// `m × 10^e` for every mantissa `m` that falls in `[lo, hi]`.
fn log_ticks_with(lo: f64, hi: f64, mantissas: &[f64]) -> Vec<f64> {
    let mut out = vec![];
    if !(lo > 0.0 && hi > lo) {
        return out;
    }
    let mut e = lo.log10().floor() as i32;
    while 10f64.powi(e) <= hi {
        for &m in mantissas {
            let v = if e < 0 {
                m / 10f64.powi(-e)
            } else {
                m * 10f64.powi(e)
            };
            if (lo..=hi).contains(&v) {
                out.push(v);
            }
        }
        e += 1;
    }
    out
}

/// Draws the mesh and the panel's contents on a linear or logarithmic chart; returns the legend
/// entries in drawing order.
fn panel_body<DB, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, Y>>,
    x: (f64, f64),
    p: &Panel,
) -> Result<Vec<Entry>>
where
    DB: DrawingBackend,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let (y0, y1) = p.y;
    chart
        .configure_mesh()
        .x_desc(p.x_desc.clone().unwrap_or_default())
        .y_desc(&p.y_desc)
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 14))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(245, 245, 245))
        .x_labels(14)
        .y_labels(7)
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .draw()
        .map_err(err)?;
    let mut entries = vec![];
    let mut shaded = false;
    for &(a, b) in &p.shade {
        let (a, b) = (a.max(x.0), b.min(x.1));
        if b <= a {
            continue;
        }
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(a, y0), (b, y1)],
                SHADE.mix(0.35).filled(),
            )))
            .map_err(err)?;
        if !shaded {
            entries.push(entry("failure window", Mark::Fill(SHADE.mix(0.5))));
        }
        shaded = true;
    }
    for (lo, hi, color, label) in &p.hbands {
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(x.0, lo.clamp(y0, y1)), (x.1, hi.clamp(y0, y1))],
                color.mix(0.45).filled(),
            )))
            .map_err(err)?;
        if let Some(l) = label {
            entries.push(entry(l.as_str(), Mark::Fill(color.mix(0.6))));
        }
    }
    for band in &p.bands {
        let mut poly: Vec<(f64, f64)> = band
            .upper
            .iter()
            .map(|&(t, u)| (t, u.clamp(y0, y1)))
            .collect();
        poly.extend(
            band.upper
                .iter()
                .rev()
                .map(|&(t, u)| (t, (-u).clamp(y0, y1))),
        );
        chart
            .draw_series(std::iter::once(Polygon::new(
                poly,
                band.color.mix(0.55).filled(),
            )))
            .map_err(err)?;
        if let Some(l) = &band.label {
            entries.push(entry(l.as_str(), Mark::Fill(band.color.mix(0.7))));
        }
    }
    for (v, color, label) in &p.hlines {
        let style = color.stroke_width(1);
        chart
            .draw_series(DashedLineSeries::new(
                vec![(x.0, *v), (x.1, *v)],
                6,
                4,
                style,
            ))
            .map_err(err)?;
        if let Some(l) = label {
            entries.push(entry(l.as_str(), Mark::Line(style, true)));
        }
    }
    for line in &p.lines {
        let style = line.color.stroke_width(line.width);
        let pts = clamp_pts(&line.pts, p.y);
        if line.dashed {
            chart
                .draw_series(DashedLineSeries::new(pts, 5, 3, style))
                .map_err(err)?;
        } else {
            chart
                .draw_series(LineSeries::new(pts, style))
                .map_err(err)?;
        }
        if let Some(l) = &line.label {
            entries.push(entry(l.as_str(), Mark::Line(style, line.dashed)));
        }
    }
    Ok(entries)
}

fn shade_of(d: &Diagnosis) -> Vec<(f64, f64)> {
    d.failures.iter().map(|f| (f.start_h, f.end_h)).collect()
}

/// Three stacked panels, one per axis; `make(axis)` builds each; the last gets the time label.
fn three_axes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    x: (f64, f64),
    make: impl Fn(usize) -> Panel,
) -> Result<()> {
    let n = area.dim_in_pixel().1 as i32;
    let (top, rest) = area.split_vertically(n * 31 / 100);
    let (mid, bot) = rest.split_vertically(n * 31 / 100);
    for (i, a) in [top, mid, bot].iter().enumerate() {
        let mut p = make(i);
        if i == 2 {
            p.x_desc = Some("time since start, h".into());
        }
        p.legend = p.legend && i == 0;
        time_panel(a, x, &p)?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The plots

fn measured_predicted<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    d: &Diagnosis,
) -> Result<()> {
    let s = &d.series;
    let x = x_range(&s.t_h);
    three_axes(area, x, |i| {
        let m = decimate(&s.t_h, |k| s.measured[k][i], x, COLS);
        let p = decimate(&s.t_h, |k| s.predicted[k][i], x, COLS);
        let lo = m
            .iter()
            .chain(&p)
            .map(|q| q.1)
            .fold(f64::INFINITY, f64::min);
        let hi = m
            .iter()
            .chain(&p)
            .map(|q| q.1)
            .fold(f64::NEG_INFINITY, f64::max);
        let pad = ((hi - lo) * 0.08).max(1e-6);
        let (lo, hi) = if lo.is_finite() && hi.is_finite() {
            (lo - pad, hi + pad)
        } else {
            (-1.0, 1.0)
        };
        Panel {
            caption: None,
            y_desc: format!("A_{}, m/s²", AXES[i]),
            y: (lo, hi),
            lines: vec![
                Line {
                    label: Some("measured".into()),
                    color: MEASURED,
                    width: 4,
                    dashed: false,
                    pts: m,
                },
                Line {
                    label: Some("predicted (model)".into()),
                    color: PREDICTED,
                    width: 1,
                    dashed: true,
                    pts: p,
                },
            ],
            legend: true,
            ..Panel::default()
        }
    })
}

/// Residual with the ±1 and ±3 floor bands; with `after`, the before/after comparison on the
/// same scale.
fn residual<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    d: &Diagnosis,
    after: Option<&Diagnosis>,
) -> Result<()> {
    let s = &d.series;
    let x = x_range(&s.t_h);
    three_axes(area, x, |i| {
        let floor = d.floor_mps2[i];
        let r = s.residual.iter().map(|r| r[i].abs());
        let lim = (quantile(r, 0.995) * 1.15)
            .max(3.5 * floor)
            .max(f64::MIN_POSITIVE);
        let (f, unit) = scale(lim);
        let y = (-lim * f, lim * f);
        let mut lines = vec![];
        let before = decimate(&s.t_h, |k| s.residual[k][i] * f, x, COLS);
        match after {
            None => lines.push(Line {
                label: Some("residual".into()),
                color: LINE,
                width: 1,
                dashed: false,
                pts: before,
            }),
            Some(a) => {
                let sa = &a.series;
                lines.push(Line {
                    label: Some(format!("before: {}", model_name(d))),
                    color: BEFORE,
                    width: 1,
                    dashed: false,
                    pts: before,
                });
                let pa = decimate(&sa.t_h, |k| sa.residual[k][i] * f, x, COLS);
                lines.push(Line {
                    label: Some(format!("after: {}", model_name(a))),
                    color: AFTER,
                    width: 1,
                    dashed: false,
                    pts: pa,
                });
            }
        }
        let rms = |dd: &Diagnosis| format!("RMS/floor {:.2}", dd.residual_rms_over_floor[i]);
        let caption = match after {
            None => format!("{} axis: {}", AXES[i], rms(d)),
            Some(a) => format!(
                "{} axis: RMS/floor {:.2} → {:.2}",
                AXES[i], d.residual_rms_over_floor[i], a.residual_rms_over_floor[i]
            ),
        };
        Panel {
            caption: Some(caption),
            y_desc: format!("residual, {unit}m/s²"),
            y,
            lines,
            hbands: vec![
                (
                    -3.0 * floor * f,
                    3.0 * floor * f,
                    BAND3,
                    Some("±3 × noise floor".into()),
                ),
                (
                    -floor * f,
                    floor * f,
                    BAND1,
                    Some("±1 × noise floor".into()),
                ),
            ],
            shade: if after.is_none() { shade_of(d) } else { vec![] },
            legend: true,
            ..Panel::default()
        }
    })
}

fn innovations<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, d: &Diagnosis) -> Result<()> {
    let s = &d.series;
    let x = x_range(&s.t_h);
    three_axes(area, x, |i| {
        // The first updates start from a wide prior: the range follows the typical 3σ band and
        // the bulk of the innovations, not the first few.
        let sig = quantile(s.innovation_sigma.iter().map(|v| v[i]), 0.5);
        let lim = (quantile(s.innovation.iter().map(|v| v[i].abs()), 0.99) * 1.15)
            .max(4.0 * sig)
            .max(f64::MIN_POSITIVE);
        let (f, unit) = scale(lim);
        let up1 = decimate(&s.t_h, |k| s.innovation_sigma[k][i] * f, x, COLS);
        let up3: Vec<(f64, f64)> = up1.iter().map(|&(t, u)| (t, 3.0 * u)).collect();
        Panel {
            caption: Some(format!("{} axis", AXES[i])),
            y_desc: format!("innovation, {unit}m/s²"),
            y: (-lim * f, lim * f),
            bands: vec![
                Band {
                    label: Some("±3σ".into()),
                    color: BAND3,
                    upper: up3,
                },
                Band {
                    label: Some("±1σ".into()),
                    color: BAND1,
                    upper: up1,
                },
            ],
            lines: vec![Line {
                label: Some("innovation".into()),
                color: LINE,
                width: 1,
                dashed: false,
                pts: decimate(&s.t_h, |k| s.innovation[k][i] * f, x, COLS),
            }],
            shade: shade_of(d),
            legend: true,
            ..Panel::default()
        }
    })
}

fn whitened<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, d: &Diagnosis) -> Result<()> {
    let s = &d.series;
    let x = x_range(&s.t_h);
    three_axes(area, x, |i| {
        let lim = (quantile(s.whitened.iter().map(|v| v[i].abs()), 0.995) * 1.15).max(4.5);
        Panel {
            caption: Some(format!("{} axis", AXES[i])),
            y_desc: "whitened innovation, σ units".into(),
            y: (-lim, lim),
            hbands: vec![
                (-3.0, 3.0, BAND3, Some("±3".into())),
                (-1.0, 1.0, BAND1, Some("±1".into())),
            ],
            lines: vec![Line {
                label: Some("whitened innovation".into()),
                color: LINE,
                width: 1,
                dashed: false,
                pts: decimate(&s.t_h, |k| s.whitened[k][i], x, COLS),
            }],
            shade: shade_of(d),
            legend: true,
            ..Panel::default()
        }
    })
}

/// NIS/3: for one diagnosis the raw values (faint) and the rolling mean with its band; for two,
/// the rolling means before and after.
fn nis<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    ds: &[&Diagnosis],
    raw: bool,
) -> Result<()> {
    let s0 = &ds[0].series;
    let x = x_range(&s0.t_h);
    let rolled: Vec<_> = ds.iter().map(|d| rolling_nis(&d.series)).collect();
    let (_, w, band) = &rolled[0];
    let window_h = *w as f64 * period_h(&s0.t_h);
    let roll_hi = rolled
        .iter()
        .flat_map(|r| r.0.iter().map(|p| p.1))
        .fold(0.0f64, |a, b| if b.is_finite() { a.max(b) } else { a });
    let raw_q = if raw {
        quantile(s0.nis.iter().map(|v| v / 3.0), 0.995)
    } else {
        0.0
    };
    let top = (roll_hi * 1.3).max(band[1] * 1.4).max(raw_q).max(2.0);
    // A log axis: NIS/3 spans decades (χ²(3)/3 of single updates reaches down to 1e-3, a
    // missing effect drives it to hundreds), and equal ratios around 1 look equal.
    let roll_lo = quantile(rolled.iter().flat_map(|r| r.0.iter().map(|p| p.1)), 0.01);
    let raw_lo = if raw {
        quantile(s0.nis.iter().map(|v| v / 3.0), 0.02)
    } else {
        f64::INFINITY
    };
    let bottom = (roll_lo * 0.8)
        .min(band[0] * 0.8)
        .min(raw_lo)
        .clamp(NIS_LOG_FLOOR, 0.5);
    let mut lines = vec![];
    if raw {
        lines.push(Line {
            label: Some("NIS/3 of each update (χ²(3)/3)".into()),
            color: RGBColor(190, 190, 190),
            width: 1,
            dashed: false,
            pts: decimate(&s0.t_h, |k| s0.nis[k] / 3.0, x, COLS),
        });
    }
    let colors = [if raw { LINE } else { BEFORE }, AFTER];
    for (j, (d, r)) in ds.iter().zip(&rolled).enumerate() {
        let label = if raw {
            format!("rolling {} mean of NIS/3", hours_label(window_h))
        } else {
            format!(
                "{}: {}",
                if j == 0 { "before" } else { "after" },
                model_name(d)
            )
        };
        lines.push(Line {
            label: Some(label),
            color: colors[j.min(1)],
            width: 2,
            dashed: false,
            pts: decimate(
                &r.0.iter().map(|p| p.0).collect::<Vec<_>>(),
                |k| r.0[k].1,
                x,
                COLS,
            ),
        });
    }
    let p = Panel {
        caption: Some(format!(
            "95 % band of a {} mean: {:.2}–{:.2}; mean NIS/3 over the run {:.2} ({:.1} % band {:.2}–{:.2}, the one the verdict uses){}",
            hours_label(window_h),
            band[0],
            band[1],
            ds[0].nis_mean,
            100.0 * crate::consistency::Thresholds::default().nis_band_prob,
            ds[0].consistency.nis_band[0],
            ds[0].consistency.nis_band[1],
            if ds.len() > 1 { format!(" → {:.2}", ds[ds.len() - 1].nis_mean) } else { String::new() }
        )),
        x_desc: Some("time since start, h".into()),
        y_desc: "NIS / 3 (dimensionless, log scale)".into(),
        y: (bottom, top),
        log_y: true,
        lines,
        hbands: vec![(band[0], band[1], BAND1, Some(format!("95 % band of the {} mean", hours_label(window_h))))],
        hlines: vec![(1.0, RGBColor(0, 0, 0), Some("1 (model consistent)".into()))],
        shade: if raw { shade_of(ds[0]) } else { vec![] },
        legend: true,
        ..Panel::default()
    };
    time_panel(area, x, &p)
}

fn hours_label(h: f64) -> String {
    if (h - h.round()).abs() < 0.05 && h >= 1.0 {
        format!("{:.0}-h", h)
    } else if h >= 1.0 {
        format!("{h:.1}-h")
    } else {
        format!("{:.0}-min", h * 60.0)
    }
}

fn acf<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, d: &Diagnosis) -> Result<()> {
    let wh = &d.whiteness;
    let (cap, rest) = area.split_vertically(24);
    cap.draw(&Text::new(
        format!(
            "Ljung–Box Q = {:.1} on {:.0} dof (three axes), p = {}; dashed: ±1.96/√N = ±{:.3} (95 % bound for a white sequence)",
            wh.ljung_box_q,
            wh.dof,
            fmt_p(wh.p_value),
            wh.acf_bound95
        ),
        (80, 4),
        (FONT, 14),
    ))
    .map_err(err)?;
    let m = wh.acf.len();
    let lim = wh
        .acf
        .iter()
        .flat_map(|a| a.iter().map(|v| v.abs()))
        .fold(0.0f64, |a, b| if b.is_finite() { a.max(b) } else { a })
        .max(2.0 * wh.acf_bound95)
        .max(0.05)
        * 1.1;
    for (i, a) in rest.split_evenly((1, 3)).iter().enumerate() {
        let mut chart = ChartBuilder::on(a)
            .margin_left(6)
            .margin_right(12)
            .margin_top(4)
            .margin_bottom(4)
            .caption(format!("{} axis", AXES[i]), (FONT, 14))
            .x_label_area_size(42)
            .y_label_area_size(if i == 0 { 70 } else { 46 })
            .build_cartesian_2d(0.0..(m as f64 + 0.5), -lim..lim)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(format!(
                "lag, updates ({})",
                minutes_label(period_h(&d.series.t_h))
            ))
            .y_desc(if i == 0 {
                "autocorrelation (dimensionless)"
            } else {
                ""
            })
            .label_style((FONT, 12))
            .axis_desc_style((FONT, 13))
            .bold_line_style(RGBColor(225, 225, 225))
            .light_line_style(RGBColor(245, 245, 245))
            .x_labels(6)
            .y_labels(7)
            .x_label_formatter(&|v| tick(*v))
            .y_label_formatter(&|v| tick(*v))
            .draw()
            .map_err(err)?;
        let b = wh.acf_bound95;
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(0.0, -b), (m as f64 + 0.5, b)],
                BAND3.mix(0.5).filled(),
            )))
            .map_err(err)?;
        for v in [-b, b] {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(0.0, v), (m as f64 + 0.5, v)],
                    5,
                    3,
                    BLACK.stroke_width(1),
                ))
                .map_err(err)?;
        }
        // (lag, clamped value, colour: red beyond the bound) of each stem.
        let stems: Vec<(f64, f64, RGBColor)> = wh
            .acf
            .iter()
            .enumerate()
            .map(|(k, a)| {
                let v = if a[i].is_finite() {
                    a[i].clamp(-lim, lim)
                } else {
                    0.0
                };
                let color = if v.abs() > b {
                    PREDICTED
                } else {
                    AXIS_COLORS[i]
                };
                ((k + 1) as f64, v, color)
            })
            .collect();
        chart
            .draw_series(
                stems
                    .iter()
                    .map(|&(x, v, c)| PathElement::new(vec![(x, 0.0), (x, v)], c.stroke_width(2))),
            )
            .map_err(err)?;
        chart
            .draw_series(
                stems
                    .iter()
                    .map(|&(x, v, c)| Circle::new((x, v), 2, c.filled())),
            )
            .map_err(err)?;
    }
    Ok(())
}

fn minutes_label(h: f64) -> String {
    let s = h * 3600.0;
    if s >= 60.0 && (s / 60.0 - (s / 60.0).round()).abs() < 1e-6 {
        format!("{:.0} min each", s / 60.0)
    } else {
        format!("{} s each", tick(s))
    }
}

/// p-value for display ([`crate::format::p_value`]: one style everywhere).
pub fn fmt_p(p: f64) -> String {
    crate::format::p_value(p, f64::NAN)
}

/// Draws category labels under a chart's x axis at the given data x positions.
fn category_labels<
    DB: DrawingBackend,
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>,
>(
    area: &DrawingArea<DB, Shift>,
    chart: &ChartContext<DB, Cartesian2d<X, Y>>,
    labels: &[(f64, String)],
    y_bottom: f64,
    size: u32,
) -> Result<()> {
    let base = area.get_base_pixel();
    for (x, l) in labels {
        let (px, py) = chart.backend_coord(&(*x, y_bottom));
        let style =
            TextStyle::from((FONT, size).into_font()).pos(plotters::style::text_anchor::Pos::new(
                plotters::style::text_anchor::HPos::Center,
                plotters::style::text_anchor::VPos::Top,
            ));
        area.draw(&Text::new(l.clone(), (px - base.0, py - base.1 + 6), style))
            .map_err(err)?;
    }
    Ok(())
}

fn correlations<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, d: &Diagnosis) -> Result<()> {
    let c = &d.correlations;
    let n = c.len().max(1);
    let bound = c.first().map(|r| r.bound99).unwrap_or(0.0);
    let lim = c
        .iter()
        .flat_map(|r| r.corr.iter().map(|v| v.abs()))
        .fold(0.0f64, |a, b| if b.is_finite() { a.max(b) } else { a })
        .max(2.0 * bound)
        .max(0.05)
        * 1.1;
    let lim = lim.min(1.05);
    let (plot, strip) = with_legend_strip(area);
    let mut chart = ChartBuilder::on(&plot)
        .margin_left(8)
        .margin_right(8)
        .margin_top(8)
        .margin_bottom(4)
        .x_label_area_size(50)
        .y_label_area_size(78)
        .build_cartesian_2d(0.0..n as f64, -lim..lim)
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .x_desc("regressor (A = specific force in the platform frame, m/s²; t = time; temp = temperature)")
        .y_desc("correlation with residual (dimensionless)")
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 14))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(245, 245, 245))
        .y_labels(7)
        .y_label_formatter(&|v| tick(*v))
        .draw()
        .map_err(err)?;
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(0.0, -bound), (n as f64, bound)],
            BAND3.mix(0.5).filled(),
        )))
        .map_err(err)?;
    let mut entries = vec![entry(
        format!("99 % bound for no correlation (±{bound:.3})"),
        Mark::Fill(BAND3.mix(0.7)),
    )];
    for (i, color) in AXIS_COLORS.iter().enumerate() {
        chart
            .draw_series(c.iter().enumerate().map(|(k, r)| {
                let x0 = k as f64 + 0.15 + 0.24 * i as f64;
                let v = if r.corr[i].is_finite() {
                    r.corr[i].clamp(-lim, lim)
                } else {
                    0.0
                };
                Rectangle::new([(x0, 0.0), (x0 + 0.22, v)], color.filled())
            }))
            .map_err(err)?;
        let label = format!("{} axis residual", AXES[i]);
        entries.push(entry(label, Mark::Fill(color.to_rgba())));
    }
    let labels: Vec<(f64, String)> = c
        .iter()
        .enumerate()
        .map(|(k, r)| (k as f64 + 0.5, r.regressor.clone()))
        .collect();
    let size = if n > 14 { 10 } else { 13 };
    category_labels(&plot, &chart, &labels, -lim, size)?;
    legend_strip(&strip, &entries)
}

fn ladder<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, input: &ReportInput) -> Result<()> {
    let r = &input.ladder;
    let n = r.len().max(1);
    let vals = r
        .iter()
        .flat_map(|g| g.residual_rms_over_floor.iter().copied())
        .filter(|v| v.is_finite() && *v > 0.0);
    let hi = vals.clone().fold(1.0f64, f64::max) * 1.5;
    let lo = vals.fold(1.0f64, f64::min).min(0.8) * 0.8;
    let notes = ladder_estimates(r);
    let (chart_area, text_area) = split_notes(area, notes.len());
    let (plot, strip) = with_legend_strip(&chart_area);
    let mut chart = ChartBuilder::on(&plot)
        .margin_left(8)
        .margin_right(8)
        .margin_top(8)
        .margin_bottom(4)
        .x_label_area_size(48)
        .y_label_area_size(78)
        .build_cartesian_2d(
            -0.5..(n as f64 - 0.5),
            (lo..hi).log_scale().with_key_points(log_ticks(lo, hi)),
        )
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .x_desc("rung of the ladder (model)")
        .y_desc("residual RMS / noise floor (log scale)")
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 14))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(245, 245, 245))
        .y_labels(8)
        .y_label_formatter(&|v| tick(*v))
        .draw()
        .map_err(err)?;
    let floor_style = BLACK.stroke_width(1);
    chart
        .draw_series(DashedLineSeries::new(
            vec![(-0.5, 1.0), (n as f64 - 0.5, 1.0)],
            6,
            4,
            floor_style,
        ))
        .map_err(err)?;
    let mut entries = vec![entry(
        "1 = noise floor (model complete)",
        Mark::Line(floor_style, true),
    )];
    for (i, color) in AXIS_COLORS.iter().enumerate() {
        let pts: Vec<(f64, f64)> = r
            .iter()
            .enumerate()
            .map(|(k, g)| (k as f64, g.residual_rms_over_floor[i].clamp(lo, hi)))
            .collect();
        let style = color.stroke_width(2);
        chart
            .draw_series(LineSeries::new(pts.clone(), style))
            .map_err(err)?;
        entries.push(entry(format!("{} axis", AXES[i]), Mark::Line(style, false)));
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
            .map_err(err)?;
    }
    let labels: Vec<(f64, String)> = r
        .iter()
        .enumerate()
        .map(|(k, g)| {
            let name = if k == 0 {
                if g.model.is_empty() {
                    "paper".to_string()
                } else {
                    format!("paper + {}", g.model.join(" + "))
                }
            } else {
                let prev = &r[k - 1].model;
                let added: Vec<&str> = g
                    .model
                    .iter()
                    .filter(|m| !prev.contains(m))
                    .map(|s| s.as_str())
                    .collect();
                format!("+ {}", added.join(" + "))
            };
            (k as f64, format!("{k}: {name}"))
        })
        .collect();
    category_labels(&plot, &chart, &labels, lo, 13)?;
    legend_strip(&strip, &entries)?;
    draw_notes(&text_area, &notes)
}

/// Height of one line of text under a chart, px.
const LINE_H: usize = 16;

/// Height of `lines` lines of notes under a chart (with their margin), px.
fn notes_height(lines: usize) -> u32 {
    if lines == 0 {
        0
    } else {
        (LINE_H * lines + 8) as u32
    }
}

/// Splits off the strip for `lines` lines of notes at the bottom of `area`.
fn split_notes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    lines: usize,
) -> (DrawingArea<DB, Shift>, DrawingArea<DB, Shift>) {
    let h = area.dim_in_pixel().1 as i32;
    area.split_vertically(h - notes_height(lines) as i32)
}

/// Draws lines of notes top-down in `area`.
fn draw_notes<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, notes: &[String]) -> Result<()> {
    for (k, line) in notes.iter().enumerate() {
        let y = 4 + (LINE_H * k) as i32;
        area.draw(&Text::new(line.clone(), (12, y), (FONT, 12)))
            .map_err(err)?;
    }
    Ok(())
}

/// The name of the temperature-drift effect.
const TEMP_DRIFT: &str = "temp-drift";

/// Whether the report plots the temperature of diagnosis `d`: the recording has temperatures and
/// either they vary, or temperature drift is a tested candidate or in the model. (A constant
/// temperature leaves temperature drift untestable: nothing to see.)
pub fn shows_temperature(d: &Diagnosis) -> bool {
    let t: Vec<f64> = d
        .series
        .temp_c
        .iter()
        .copied()
        .filter(|t| t.is_finite())
        .collect();
    let varies = t.iter().any(|v| (v - t[0]).abs() > 1e-6);
    let named = d.model.iter().any(|m| m == TEMP_DRIFT)
        || d.ranking
            .iter()
            .any(|c| c.effect == TEMP_DRIFT && c.untestable.is_none());
    !t.is_empty() && (varies || named)
}

/// Where temperature drift stands in diagnosis `d`: one sentence.
fn temperature_status(input: &ReportInput, d: usize) -> String {
    let dg = &input.diagnoses[d];
    if dg.model.iter().any(|m| m == TEMP_DRIFT) {
        return format!("{TEMP_DRIFT} is in this model");
    }
    let Some((k, c)) = dg
        .ranking
        .iter()
        .enumerate()
        .find(|(_, c)| c.effect == TEMP_DRIFT)
    else {
        return format!("{TEMP_DRIFT} is not in the catalog of this run");
    };
    match &c.untestable {
        Some(why) => format!("{TEMP_DRIFT} could not be tested: {why}"),
        None => format!(
            "{TEMP_DRIFT}: candidate #{} of {}, p (Holm) = {}",
            k + 1,
            dg.ranking.len(),
            crate::format::p_value(c.p_adjusted, c.ln_p_adjusted)
        ),
    }
}

/// The temperature-drift estimates, value ± 1σ ([`crate::format::pm`]): the model's when it is
/// in the model, else the score test's one-step estimates.
pub fn temperature_notes(input: &ReportInput, d: usize) -> Vec<String> {
    let dg = &input.diagnoses[d];
    let one = |name: &str, unit: &str, v: f64, s: f64| {
        format!("{name} = {} {unit}", crate::format::pm(v, s))
    };
    let (what, items): (&str, Vec<String>) = if dg.model.iter().any(|m| m == TEMP_DRIFT) {
        let names: Vec<&str> = crate::catalog::by_name(TEMP_DRIFT)
            .map(|e| e.params().iter().map(|p| p.name).collect())
            .unwrap_or_default();
        let params = input
            .ladder
            .get(d)
            .map(|r| &r.effect_params[..])
            .unwrap_or(&[]);
        let items = params
            .iter()
            .filter(|p| names.contains(&p.0.as_str()))
            .map(|(n, u, v, s)| one(n, u, *v, *s))
            .collect();
        ("estimated", items)
    } else {
        let items = dg
            .ranking
            .iter()
            .filter(|c| c.effect == TEMP_DRIFT && c.untestable.is_none())
            .flat_map(|c| c.params.iter())
            .map(|p| one(&p.name, &p.unit, p.value, p.sigma))
            .collect();
        ("score-test size (one step from this model)", items)
    };
    if items.is_empty() {
        return vec![];
    }
    vec![format!("{TEMP_DRIFT} {what}: {}", items.join("; "))]
}

/// The recording's temperature over time, the failure windows shaded; the caption and the notes
/// say where temperature drift stands.
fn temperature<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    input: &ReportInput,
    d: usize,
) -> Result<()> {
    let dg = &input.diagnoses[d];
    let s = &dg.series;
    let x = x_range(&s.t_h);
    let notes = temperature_notes(input, d);
    let (chart_area, text_area) = split_notes(area, notes.len());
    let pts = decimate(&s.t_h, |k| s.temp_c[k], x, COLS);
    let lo = pts.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let hi = pts.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
    let pad = ((hi - lo) * 0.08).max(0.5);
    let y = if lo.is_finite() && hi.is_finite() {
        (lo - pad, hi + pad)
    } else {
        (0.0, 1.0)
    };
    let p = Panel {
        caption: Some(temperature_status(input, d)),
        x_desc: Some("time since start, h".into()),
        y_desc: "temperature, °C".into(),
        y,
        lines: vec![Line {
            label: Some("temp_c (recording)".into()),
            color: LINE,
            width: 2,
            dashed: false,
            pts,
        }],
        shade: shade_of(dg),
        legend: true,
        ..Panel::default()
    };
    time_panel(&chart_area, x, &p)?;
    draw_notes(&text_area, &notes)
}
/// Estimates shown per line under the ladder.
const ESTIMATES_PER_LINE: usize = 4;

/// The estimates of each rung's added effects, value ± 1σ with the digits the 1σ calls for
/// ([`crate::format::pm`]), a few per line.
pub fn ladder_estimates(rungs: &[super::Rung]) -> Vec<String> {
    let mut out = vec![];
    for (k, r) in rungs.iter().enumerate().skip(1) {
        let prev = rungs[k - 1].effect_params.len();
        let added: Vec<String> = r
            .effect_params
            .iter()
            .skip(prev)
            .map(|(name, unit, v, s)| format!("{name} = {} {unit}", crate::format::pm(*v, *s)))
            .collect();
        for (j, chunk) in added.chunks(ESTIMATES_PER_LINE).enumerate() {
            let head = if j == 0 {
                format!("rung {k} estimates:")
            } else {
                "   ".to_string()
            };
            out.push(format!("{head} {}", chunk.join("; ")));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::consistency::{assess, Thresholds};
    use crate::diagnose::types::{Candidate, Rung, Whiteness};
    use crate::report::ReportInput;

    /// A 10-h run at one update a minute: a varying temperature, NIS of a consistent model but
    /// for a failure window, and a ladder that added temp-drift.
    fn input() -> ReportInput {
        let n = 600;
        let t_h: Vec<f64> = (0..n).map(|j| j as f64 / 60.0).collect();
        let wave = |j: usize, f: f64| (f * j as f64).sin();
        let series = Series {
            t_h: t_h.clone(),
            measured: (0..n).map(|j| [wave(j, 0.01), 0.1, 9.8]).collect(),
            predicted: (0..n).map(|j| [wave(j, 0.01), 0.1, 9.8]).collect(),
            residual: (0..n).map(|j| [1e-4 * wave(j, 1.3); 3]).collect(),
            innovation: (0..n).map(|j| [1e-4 * wave(j, 1.7); 3]).collect(),
            innovation_sigma: vec![[1e-4; 3]; n],
            whitened: (0..n).map(|j| [wave(j, 1.7); 3]).collect(),
            nis: (0..n).map(|j| 3.0 * (1.0 + 0.9 * wave(j, 2.1))).collect(),
            temp_c: t_h.iter().map(|t| 20.0 + 0.5 * t).collect(),
        };
        let candidate = Candidate {
            effect: "temp-drift".into(),
            about: String::new(),
            statistic: 50.0,
            dof: 3.0,
            p_value: 1e-10,
            p_adjusted: 3e-10,
            ln_p_value: 1e-10f64.ln(),
            ln_p_adjusted: 3e-10f64.ln(),
            params: vec![],
            refit: None,
            untestable: None,
        };
        let d = |model: Vec<String>| Diagnosis {
            model,
            floor_mps2: [1e-4; 3],
            residual_rms_mps2: [0.7e-4; 3],
            residual_rms_over_floor: [0.7; 3],
            nis_mean: 1.0,
            nis_band95: [0.95, 1.05],
            whiteness: Whiteness {
                acf: vec![[0.01; 3]; 5],
                acf_bound95: 0.08,
                ljung_box_q: 10.0,
                dof: 15.0,
                p_value: 0.8,
            },
            failures: vec![crate::diagnose::types::FailureWindow {
                start_h: 2.0,
                end_h: 3.0,
                nis_mean: 2.0,
                worst_axis: 'x',
            }],
            correlations: crate::diagnose::correlations(&series, &[0.0; 600]),
            ranking: vec![candidate.clone()],
            confounding: vec![],
            consistency: assess(1.0, n, 0.8, [0.7; 3], 0.0, &Thresholds::default()),
            choice: None,
            verdict: String::new(),
            convergence: None,
            series: series.clone(),
        };
        let rung = |model: Vec<String>, params: Vec<(String, String, f64, f64)>| Rung {
            model,
            residual_rms_over_floor: [1.3, 1.0, 0.9],
            nis_mean: 1.0,
            whiteness_p: 0.5,
            coefficients: vec![],
            effect_params: params,
            consistent: true,
            next: None,
            next_reason: None,
        };
        let k = |n: &str, v: f64| (n.to_string(), "deg/h/degC".to_string(), v, 2.07e-7);
        ReportInput {
            title: "t".into(),
            recording: "r.csv".into(),
            description: None,
            diagnoses: vec![d(vec![]), d(vec!["temp-drift".into()])],
            ladder: vec![
                rung(vec![], vec![]),
                rung(
                    vec!["temp-drift".into()],
                    vec![k("KX", 5.54e-6), k("KY", -1.0e-6), k("KZ", 3.0e-7)],
                ),
            ],
            coefficients: vec![],
            findings: vec![],
            untrusted: vec![],
            provenance: Default::default(),
        }
    }

    /// Where the SVG `<text>` element holding exactly `label` has its text (plotters writes
    /// `<text …>label` and a newline).
    fn find_text(svg: &str, label: &str) -> Option<usize> {
        [
            format!(">{label}\n"),
            format!(">\n{label}\n"),
            format!(">{label}<"),
        ]
        .iter()
        .find_map(|p| svg.find(p.as_str()))
    }

    /// The x coordinate of the SVG `<text>` element that holds `label`.
    fn text_x(svg: &str, label: &str) -> f64 {
        let at = find_text(svg, label).expect(label);
        let start = svg[..at].rfind("<text").unwrap();
        let attr = &svg[start..at];
        let x = attr.find(" x=\"").unwrap() + 4;
        let end = attr[x..].find('"').unwrap();
        attr[x..x + end].parse().unwrap()
    }

    #[test]
    fn a_varying_temperature_is_plotted_with_the_estimates() {
        let input = input();
        let figs = figures(&input);
        assert!(figs.iter().any(|f| f.kind == Kind::Temperature(0)));
        assert_eq!(
            temperature_status(&input, 0),
            "temp-drift: candidate #1 of 1, p (Holm) = 3.00e-10"
        );
        // The model's estimates with the digits their 1σ calls for (format::pm).
        let notes = temperature_notes(&input, 1);
        assert_eq!(
            notes,
            ["temp-drift estimated: KX = 5.54e-6 ± 2.1e-7 deg/h/degC; KY = -1.00e-6 ± 2.1e-7 deg/h/degC; KZ = 3.0e-7 ± 2.1e-7 deg/h/degC"]
        );
        assert_eq!(ladder_estimates(&input.ladder).len(), 1);
        assert!(ladder_estimates(&input.ladder)[0].contains("KX = 5.54e-6 ± 2.1e-7"));
        // A constant temperature: temp-drift untestable, no temperature plot.
        let mut flat = input.diagnoses[0].clone();
        flat.series.temp_c = vec![20.0; 600];
        flat.ranking[0].untestable = Some("no varying temp_c".into());
        assert!(!shows_temperature(&flat));
        // No temperature column at all: nothing to plot.
        flat.series.temp_c = vec![f64::NAN; 600];
        assert!(!shows_temperature(&flat));
    }

    #[test]
    fn legends_sit_beside_the_plotting_area() {
        let input = input();
        let plot_right = (WIDTH as i32 - LEGEND_W) as f64;
        for fig in figures(&input) {
            let svg = svg(&fig, &input).unwrap();
            let labels: &[&str] = match fig.kind {
                Kind::Residual(_) => &["failure window", "±3 × noise floor", "residual"],
                Kind::Nis(_) => &["failure window", "1 (model consistent)"],
                Kind::Temperature(_) => &["failure window", "temp_c (recording)"],
                Kind::Correlations(_) => &["x axis residual"],
                Kind::Ladder => &["x axis"],
                _ => &[],
            };
            for l in labels {
                assert!(
                    text_x(&svg, l) > plot_right,
                    "{:?}: legend entry {l} at x = {} inside the plot",
                    fig.kind,
                    text_x(&svg, l)
                );
            }
        }
    }

    #[test]
    fn nis_is_on_a_log_axis() {
        // The rolling band and the raw values span decades; a log axis shows ticks like 0.1 and
        // 10 together with 1.
        let input = input();
        let fig = figure(Kind::Nis(0), &input);
        let svg = svg(&fig, &input).unwrap();
        assert!(svg.contains("log scale"));
        let has = |t: &str| find_text(&svg, t).is_some();
        let texts: Vec<&str> = svg
            .split("<text")
            .skip(1)
            .filter_map(|t| {
                t.split_once('>')
                    .map(|(_, r)| r.split('<').next().unwrap().trim())
            })
            .collect();
        assert!(
            has("1") && (has("0.1") || has("0.2") || has("10")),
            "{texts:?}"
        );
    }

    #[test]
    fn log_ticks_are_one_two_five() {
        assert_eq!(log_ticks(0.05, 3.0), [0.05, 0.1, 0.2, 0.5, 1.0, 2.0]);
        assert!(log_ticks(0.0, 1.0).is_empty());
        assert_eq!(log_ticks(0.64, 2.1), [0.7, 0.8, 0.9, 1.0, 2.0]);
    }

    #[test]
    fn legend_labels_wrap_at_spaces() {
        assert_eq!(
            wrap("NIS/3 of each update (χ²(3)/3) and more"),
            ["NIS/3 of each update", "(χ²(3)/3) and more"]
        );
        assert_eq!(wrap("short"), ["short"]);
    }
}
