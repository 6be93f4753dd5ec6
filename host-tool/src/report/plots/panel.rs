//! A time panel (lines, bands, shading on one chart) and the text drawn around charts.

use super::*;

pub(super) struct Line {
    pub(super) label: Option<String>,
    pub(super) color: RGBColor,
    pub(super) width: u32,
    pub(super) dashed: bool,
    pub(super) pts: Vec<(f64, f64)>,
}

/// A band ±`upper(t)` about zero.
pub(super) struct Band {
    pub(super) label: Option<String>,
    pub(super) color: RGBColor,
    pub(super) upper: Vec<(f64, f64)>,
}

#[derive(Default)]
pub(super) struct Panel {
    pub(super) caption: Option<String>,
    pub(super) x_desc: Option<String>,
    pub(super) y_desc: String,
    pub(super) y: (f64, f64),
    /// A logarithmic y axis (`y` must then be positive).
    pub(super) log_y: bool,
    pub(super) lines: Vec<Line>,
    pub(super) bands: Vec<Band>,
    /// Constant bands (lo, hi, colour, label).
    pub(super) hbands: Vec<(f64, f64, RGBColor, Option<String>)>,
    /// Horizontal reference lines (value, colour, label).
    pub(super) hlines: Vec<(f64, RGBColor, Option<String>)>,
    /// Shaded time intervals (failure windows).
    pub(super) shade: Vec<(f64, f64)>,
    /// Points of the whole series below and above the frame, when the caller counted them
    /// (else the drawn, decimated points are counted).
    pub(super) beyond: Option<[usize; 2]>,
    pub(super) legend: bool,
}

pub(super) fn clamp_pts(p: &[(f64, f64)], y: (f64, f64)) -> Vec<(f64, f64)> {
    p.iter().map(|&(t, v)| (t, v.clamp(y.0, y.1))).collect()
}

/// One time panel: the chart on the left, its legend (when `p.legend`) in the strip on the right;
/// every panel keeps the strip so stacked panels share their time axis.
pub(super) fn time_panel<DB: DrawingBackend>(
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
pub(super) fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let ticks = log_ticks_with(lo, hi, &[1.0, 2.0, 5.0]);
    if ticks.len() >= 3 {
        return ticks;
    }
    log_ticks_with(lo, hi, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
}

/// `m × 10^e` for every mantissa `m` that falls in `[lo, hi]`.
pub(super) fn log_ticks_with(lo: f64, hi: f64, mantissas: &[f64]) -> Vec<f64> {
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
pub(super) fn panel_body<DB, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, Y>>,
    x: (f64, f64),
    p: &Panel,
) -> Result<Vec<Entry>>
where
    DB: DrawingBackend,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .x_desc(p.x_desc.clone().unwrap_or_default())
        .y_desc(&p.y_desc)
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 15))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(245, 245, 245))
        .x_labels(14)
        .y_labels(7)
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .draw()
        .map_err(err)?;
    let mut entries = vec![];
    shading(chart, x, p, &mut entries)?;
    bands(chart, x, p, &mut entries)?;
    lines(chart, p, &mut entries)?;
    clipped(chart, x, p, &mut entries)?;
    Ok(entries)
}

/// The failure windows, shaded over the whole height.
fn shading<DB, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, Y>>,
    x: (f64, f64),
    p: &Panel,
    entries: &mut Vec<Entry>,
) -> Result<()>
where
    DB: DrawingBackend,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let (y0, y1) = p.y;
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
    Ok(())
}

/// Constant bands, bands about zero and reference lines.
fn bands<DB, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, Y>>,
    x: (f64, f64),
    p: &Panel,
    entries: &mut Vec<Entry>,
) -> Result<()>
where
    DB: DrawingBackend,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let (y0, y1) = p.y;
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
    Ok(())
}

/// The data lines, clamped to the frame (what lies beyond is marked by [`clipped`]).
fn lines<DB, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, Y>>,
    p: &Panel,
    entries: &mut Vec<Entry>,
) -> Result<()>
where
    DB: DrawingBackend,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
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
    Ok(())
}

/// How many points lie below and above `y` (non-finite ones are not drawn, so not counted).
pub(super) fn count_beyond(vals: impl Iterator<Item = f64>, y: (f64, f64)) -> [usize; 2] {
    vals.fold([0, 0], |[lo, hi], v| {
        [lo + usize::from(v < y.0), hi + usize::from(v > y.1)]
    })
}

/// Never a silent clip: every drawn point beyond the frame gets a red triangle at the edge it
/// crosses, and the chart says how many points lie beyond ([`Panel::beyond`] when the caller
/// counted the whole series, else the drawn points).
fn clipped<DB, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, Y>>,
    x: (f64, f64),
    p: &Panel,
    entries: &mut Vec<Entry>,
) -> Result<()>
where
    DB: DrawingBackend,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let (y0, y1) = p.y;
    let drawn: Vec<(f64, f64)> = p
        .lines
        .iter()
        .flat_map(|l| l.pts.iter().copied())
        .filter(|&(_, v)| v.is_finite() && (v < y0 || v > y1))
        .collect();
    let [below, above] = p
        .beyond
        .unwrap_or_else(|| count_beyond(drawn.iter().map(|q| q.1), p.y));
    if below + above == 0 {
        return Ok(());
    }
    let style = RED.filled();
    chart
        .draw_series(drawn.iter().map(|&(t, v)| {
            let (edge, tri) = if v > y1 {
                (y1, vec![(0, 0), (-5, 9), (5, 9)])
            } else {
                (y0, vec![(0, 0), (-5, -9), (5, -9)])
            };
            EmptyElement::at((t, edge)) + Polygon::new(tri, style)
        }))
        .map_err(err)?;
    let mut parts = vec![];
    if above > 0 {
        parts.push(format!("▲ {above} above"));
    }
    if below > 0 {
        parts.push(format!("▼ {below} below"));
    }
    let note = format!(
        "{} the frame (clipped, marked at the edge)",
        parts.join(", ")
    );
    chart
        .draw_series(std::iter::once(
            EmptyElement::at((x.0, y1))
                + Text::new(note.clone(), (8, 12), (FONT, 13).into_font().color(&RED)),
        ))
        .map_err(err)?;
    entries.push(entry(note, Mark::Fill(RED.to_rgba())));
    Ok(())
}

/// The failure windows of `d` to shade: those whose worst axis is `axis` (a window belongs to
/// one axis), or all of them on a chart of every axis (`None`: NIS, temperature).
pub(super) fn shade_of(d: &Diagnosis, axis: Option<usize>) -> Vec<(f64, f64)> {
    d.failures
        .iter()
        .filter(|f| axis.is_none_or(|i| f.worst_axis == AXES[i].chars().next().unwrap_or('x')))
        .map(|f| (f.start_h, f.end_h))
        .collect()
}

/// Three stacked panels, one per axis; `make(axis)` builds each; the last gets the time label.
pub(super) fn three_axes<DB: DrawingBackend>(
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
/// Draws category labels under a chart's x axis at the given data x positions.
pub(super) fn category_labels<
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
/// Height of one line of text under a chart, px.
pub(super) const LINE_H: usize = 18;

/// Height of `lines` lines of notes under a chart (with their margin), px.
pub(super) fn notes_height(lines: usize) -> u32 {
    if lines == 0 {
        0
    } else {
        (LINE_H * lines + 8) as u32
    }
}

/// Splits off the strip for `lines` lines of notes at the bottom of `area`.
pub(super) fn split_notes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    lines: usize,
) -> (DrawingArea<DB, Shift>, DrawingArea<DB, Shift>) {
    let h = area.dim_in_pixel().1 as i32;
    area.split_vertically(h - notes_height(lines) as i32)
}

/// Draws lines of notes top-down in `area`.
pub(super) fn draw_notes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    notes: &[String],
) -> Result<()> {
    for (k, line) in notes.iter().enumerate() {
        let y = 4 + (LINE_H * k) as i32;
        area.draw(&Text::new(line.clone(), (12, y), (FONT, 14)))
            .map_err(err)?;
    }
    Ok(())
}
