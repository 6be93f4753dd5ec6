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
use plotters::coord::Shift;
use plotters::prelude::*;

use super::ReportInput;
use crate::diagnose::types::{Diagnosis, Series};
use crate::stats::chi2_quantile;

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
const GREY: RGBColor = RGBColor(150, 150, 150);
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
        Kind::Ladder => (
            "ladder",
            "Model ladder: residual RMS / noise floor per rung (watch the error fall)".to_string(),
            400,
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
        | Kind::Correlations(d) => {
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
        Kind::Ladder,
    ];
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

fn time_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    x: (f64, f64),
    p: &Panel,
) -> Result<()> {
    let (y0, y1) = p.y;
    let mut b = ChartBuilder::on(area);
    b.margin_left(8)
        .margin_right(18)
        .margin_top(4)
        .margin_bottom(4);
    b.x_label_area_size(if p.x_desc.is_some() { 44 } else { 22 })
        .y_label_area_size(78);
    if let Some(c) = &p.caption {
        b.caption(c, (FONT, 14));
    }
    let mut chart = b.build_cartesian_2d(x.0..x.1, y0..y1).map_err(err)?;
    let x_desc = p.x_desc.clone().unwrap_or_default();
    chart
        .configure_mesh()
        .x_desc(x_desc)
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
    let mut shaded = false;
    for &(a, b) in &p.shade {
        let (a, b) = (a.max(x.0), b.min(x.1));
        if b <= a {
            continue;
        }
        let s = chart
            .draw_series(std::iter::once(Rectangle::new(
                [(a, y0), (b, y1)],
                SHADE.mix(0.35).filled(),
            )))
            .map_err(err)?;
        if !shaded && p.legend {
            s.label("failure window").legend(|(x, y)| {
                Rectangle::new([(x, y - 5), (x + 18, y + 5)], SHADE.mix(0.5).filled())
            });
        }
        shaded = true;
    }
    for (lo, hi, color, label) in &p.hbands {
        let s = chart
            .draw_series(std::iter::once(Rectangle::new(
                [(x.0, lo.clamp(y0, y1)), (x.1, hi.clamp(y0, y1))],
                color.mix(0.45).filled(),
            )))
            .map_err(err)?;
        if let (Some(l), true) = (label, p.legend) {
            let c = *color;
            s.label(l.as_str()).legend(move |(x, y)| {
                Rectangle::new([(x, y - 5), (x + 18, y + 5)], c.mix(0.6).filled())
            });
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
        let s = chart
            .draw_series(std::iter::once(Polygon::new(
                poly,
                band.color.mix(0.55).filled(),
            )))
            .map_err(err)?;
        if let (Some(l), true) = (&band.label, p.legend) {
            let c = band.color;
            s.label(l.as_str()).legend(move |(x, y)| {
                Rectangle::new([(x, y - 5), (x + 18, y + 5)], c.mix(0.7).filled())
            });
        }
    }
    for (v, color, label) in &p.hlines {
        let style = ShapeStyle {
            color: color.to_rgba(),
            filled: false,
            stroke_width: 1,
        };
        let s = chart
            .draw_series(DashedLineSeries::new(
                vec![(x.0, *v), (x.1, *v)],
                6,
                4,
                style,
            ))
            .map_err(err)?;
        if let (Some(l), true) = (label, p.legend) {
            s.label(l.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
        }
    }
    for line in &p.lines {
        let style = ShapeStyle {
            color: line.color.to_rgba(),
            filled: false,
            stroke_width: line.width,
        };
        let pts = clamp_pts(&line.pts, p.y);
        let s = if line.dashed {
            chart
                .draw_series(DashedLineSeries::new(pts, 5, 3, style))
                .map_err(err)?
        } else {
            chart
                .draw_series(LineSeries::new(pts, style))
                .map_err(err)?
        };
        if let (Some(l), true) = (&line.label, p.legend) {
            s.label(l.as_str()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], style.stroke_width(2))
            });
        }
    }
    if p.legend {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(GREY)
            .label_font((FONT, 13))
            .draw()
            .map_err(err)?;
    }
    Ok(())
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
        quantile(s0.nis.iter().map(|v| v / 3.0), 0.98)
    } else {
        0.0
    };
    let top = (quantile(rolled.iter().flat_map(|r| r.0.iter().map(|p| p.1)), 0.99) * 1.2)
        .max(band[1] * 1.4)
        .max(raw_q)
        .max(2.0)
        .min(roll_hi.max(band[1] * 1.4) * 1.2);
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
            "95 % band of a {} mean: {:.2}–{:.2}; mean NIS/3 over the run {:.2} (band {:.2}–{:.2}){}",
            hours_label(window_h),
            band[0],
            band[1],
            ds[0].nis_mean,
            ds[0].nis_band95[0],
            ds[0].nis_band95[1],
            if ds.len() > 1 { format!(" → {:.2}", ds[ds.len() - 1].nis_mean) } else { String::new() }
        )),
        x_desc: Some("time since start, h".into()),
        y_desc: "NIS / 3 (dimensionless)".into(),
        y: (0.0, top),
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

/// p-value for display.
pub fn fmt_p(p: f64) -> String {
    if !p.is_finite() {
        "n/a".into()
    } else if p >= 0.001 {
        format!("{p:.3}")
    } else if p == 0.0 {
        "< 1e-300".into()
    } else {
        format!("{p:.1e}")
    }
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
    let mut chart = ChartBuilder::on(area)
        .margin_left(8)
        .margin_right(18)
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
        .map_err(err)?
        .label(format!("99 % bound for no correlation (±{bound:.3})"))
        .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 18, y + 5)], BAND3.mix(0.7).filled()));
    for (i, color) in AXIS_COLORS.iter().enumerate() {
        let s = chart
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
        let color = *color;
        s.label(format!("{} axis residual", AXES[i]))
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 18, y + 5)], color.filled()));
    }
    let labels: Vec<(f64, String)> = c
        .iter()
        .enumerate()
        .map(|(k, r)| (k as f64 + 0.5, r.regressor.clone()))
        .collect();
    let size = if n > 14 { 10 } else { 13 };
    category_labels(area, &chart, &labels, -lim, size)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(GREY)
        .label_font((FONT, 13))
        .draw()
        .map_err(err)?;
    Ok(())
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
    let mut chart = ChartBuilder::on(area)
        .margin_left(8)
        .margin_right(18)
        .margin_top(8)
        .margin_bottom(4)
        .x_label_area_size(48)
        .y_label_area_size(78)
        .build_cartesian_2d(-0.5..(n as f64 - 0.5), (lo..hi).log_scale())
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
        .map_err(err)?
        .label("1 = noise floor (model complete)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], floor_style));
    for (i, color) in AXIS_COLORS.iter().enumerate() {
        let pts: Vec<(f64, f64)> = r
            .iter()
            .enumerate()
            .map(|(k, g)| (k as f64, g.residual_rms_over_floor[i].clamp(lo, hi)))
            .collect();
        let style = color.stroke_width(2);
        chart
            .draw_series(LineSeries::new(pts.clone(), style))
            .map_err(err)?
            .label(format!("{} axis", AXES[i]))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
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
    category_labels(area, &chart, &labels, lo, 13)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(GREY)
        .label_font((FONT, 13))
        .draw()
        .map_err(err)?;
    Ok(())
}
