//! What changed along the ladder, in one figure of three panels: mean NIS/3 per rung against the
//! 99.9 % band the verdict uses, Ljung–Box p per rung against the whiteness level, and the drift
//! coefficients that moved most, in units of their final 1σ. A modest effect barely moves the
//! residual RMS; these three move by orders of magnitude.

use super::*;
use crate::consistency::Thresholds;
use crate::diagnose::types::Rung;

/// Coefficients drawn in the third panel.
const MOVED_DRAWN: usize = 6;
/// Lowest p-value the whiteness panel shows (a smaller one, or 0, is drawn at the edge).
const P_FLOOR: f64 = 1e-300;

/// The three panels side by side.
pub(super) fn what_changed<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    input: &ReportInput,
) -> Result<()> {
    let panels = area.split_evenly((1, 3));
    nis_per_rung(&panels[0], &input.diagnoses)?;
    whiteness_per_rung(&panels[1], &input.diagnoses)?;
    shifts(&panels[2], &input.ladder)
}

/// Rung labels under the x axis: `0`, `1`, … (the rungs are named in the table beside).
fn rung_axis(n: usize) -> std::ops::Range<f64> {
    -0.5..(n as f64 - 0.5)
}

/// `0: paper`, `1: + temp-drift`, …: each rung by what it added.
fn rung_labels(ds: &[Diagnosis]) -> Vec<(f64, String)> {
    ds.iter()
        .enumerate()
        .map(|(k, d)| {
            let before = k.checked_sub(1).map(|j| ds[j].model.as_slice());
            (k as f64, format!("{k}: {}", rung_name(&d.model, before)))
        })
        .collect()
}

/// A point per rung: blue when it passes, red when it fails.
fn pass_color(ok: bool) -> RGBColor {
    if ok {
        LINE
    } else {
        RED
    }
}

fn nis_per_rung<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, ds: &[Diagnosis]) -> Result<()> {
    let vals = ds
        .iter()
        .flat_map(|d| {
            [
                d.nis_mean,
                d.consistency.nis_band[0],
                d.consistency.nis_band[1],
            ]
        })
        .filter(|v| v.is_finite());
    let hi = vals.clone().fold(1.0f64, f64::max);
    let lo = vals.fold(1.0f64, f64::min);
    let pad = ((hi - lo) * 0.15).max(0.02);
    let prob = 100.0 * Thresholds::default().nis_band_prob;
    let mut chart = ChartBuilder::on(area)
        .margin(8)
        .caption(format!("mean NIS/3, {prob:.1} % band"), (FONT, 15))
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(rung_axis(ds.len()), (lo - pad)..(hi + pad))
        .map_err(err)?;
    rung_mesh(&mut chart, "mean NIS/3 (1: consistent)")?;
    category_labels(area, &chart, &rung_labels(ds), lo - pad, 13)?;
    for (k, d) in ds.iter().enumerate() {
        let [b0, b1] = d.consistency.nis_band;
        let x = k as f64;
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(x - 0.18, b0), (x + 0.18, b1)],
                BAND1.mix(0.45).filled(),
            )))
            .map_err(err)?;
        let ok = d.nis_mean >= b0 && d.nis_mean <= b1;
        chart
            .draw_series(std::iter::once(Circle::new(
                (x, d.nis_mean),
                6,
                pass_color(ok).filled(),
            )))
            .map_err(err)?;
    }
    Ok(())
}

fn whiteness_per_rung<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    ds: &[Diagnosis],
) -> Result<()> {
    let alpha = Thresholds::default().whiteness_alpha;
    let lo = ds
        .iter()
        .map(|d| d.whiteness.p_value.max(P_FLOOR))
        .fold(alpha, f64::min)
        * 1e-2;
    let y = (lo..1.0).log_scale().with_key_points(decade_ticks(lo));
    let mut chart = ChartBuilder::on(area)
        .margin(8)
        .caption("Ljung–Box p (whiteness)", (FONT, 15))
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(rung_axis(ds.len()), y)
        .map_err(err)?;
    rung_mesh(&mut chart, "p (log scale)")?;
    category_labels(area, &chart, &rung_labels(ds), lo, 13)?;
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(-0.5, alpha), (ds.len() as f64 - 0.5, 1.0)],
            BAND1.mix(0.25).filled(),
        )))
        .map_err(err)?;
    chart
        .draw_series(DashedLineSeries::new(
            vec![(-0.5, alpha), (ds.len() as f64 - 0.5, alpha)],
            5,
            3,
            BLACK.stroke_width(1),
        ))
        .map_err(err)?;
    for (k, d) in ds.iter().enumerate() {
        let p = d.whiteness.p_value;
        let shown = if p.is_finite() { p.max(lo) } else { lo };
        chart
            .draw_series(std::iter::once(Circle::new(
                (k as f64, shown),
                6,
                pass_color(p >= alpha).filled(),
            )))
            .map_err(err)?;
        let label = format!("p = {}", fmt_p(p));
        chart
            .draw_series(std::iter::once(
                EmptyElement::at((k as f64, shown)) + Text::new(label, (9, -8), (FONT, 13)),
            ))
            .map_err(err)?;
    }
    Ok(())
}

/// Every tenth decade between `lo` and 1 (a p-value axis spans hundreds of decades).
fn decade_ticks(lo: f64) -> Vec<f64> {
    let decades = -lo.log10().floor();
    let step = (decades / 5.0).ceil().max(1.0);
    let mut t = vec![];
    let mut e = 0.0;
    while e <= decades {
        t.push(10f64.powf(-e));
        e += step;
    }
    t
}

fn shifts<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, rungs: &[Rung]) -> Result<()> {
    let m = crate::report::story::moved(rungs);
    let m = &m[..m.len().min(MOVED_DRAWN)];
    let top = m.iter().map(|c| c.sigmas.abs()).fold(3.0f64, f64::max) * 1.15;
    let mut chart = ChartBuilder::on(area)
        .margin(8)
        .caption("moved most, final 1σ", (FONT, 15))
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(rung_axis(m.len().max(1)), -top..top)
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .y_desc("(final − start) / 1σ")
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 14))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(245, 245, 245))
        .y_label_formatter(&|v| tick(*v))
        .draw()
        .map_err(err)?;
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(-0.5, -3.0), (m.len().max(1) as f64 - 0.5, 3.0)],
            BAND3.mix(0.5).filled(),
        )))
        .map_err(err)?;
    chart
        .draw_series(m.iter().enumerate().map(|(k, c)| {
            let x = k as f64;
            let color = if c.sigmas.abs() > 3.0 { RED } else { LINE };
            Rectangle::new([(x - 0.3, 0.0), (x + 0.3, c.sigmas)], color.filled())
        }))
        .map_err(err)?;
    let labels: Vec<(f64, String)> = m
        .iter()
        .enumerate()
        .map(|(k, c)| (k as f64, c.name.clone()))
        .collect();
    category_labels(area, &chart, &labels, -top, 13)
}

/// The mesh of a per-rung panel (the rungs are labelled by [`category_labels`]).
fn rung_mesh<DB, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, Y>>,
    y_desc: &str,
) -> Result<()>
where
    DB: DrawingBackend,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .y_desc(y_desc)
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 14))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(245, 245, 245))
        .y_label_formatter(&|v| {
            if *v < 1e-3 {
                format!("1e{:.0}", v.log10().round())
            } else {
                tick(*v)
            }
        })
        .draw()
        .map_err(err)?;
    Ok(())
}
