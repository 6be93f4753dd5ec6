//! The model ladder: residual RMS / floor per rung, and each rung's added estimates.

use super::*;

/// The model ladder's plot: each rung's residual RMS / noise floor per axis against the floor
/// (1), the rungs named below, their added estimates under the chart.
pub(super) fn ladder<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    input: &ReportInput,
) -> Result<()> {
    let r = &input.ladder;
    let n = r.len().max(1);
    let (lo, hi) = rms_range(r);
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
        .label_style((FONT, 14))
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
    category_labels(&plot, &chart, &rung_labels(r), lo, 13)?;
    legend_strip(&strip, &entries)?;
    draw_notes(&text_area, &notes)
}

/// The y range of the ladder (residual RMS / floor, log scale): the rungs' finite values and 1,
/// with room above and below.
fn rms_range(rungs: &[crate::diagnose::types::Rung]) -> (f64, f64) {
    let vals = rungs
        .iter()
        .flat_map(|g| g.residual_rms_over_floor.iter().copied())
        .filter(|v| v.is_finite() && *v > 0.0);
    let hi = vals.clone().fold(1.0f64, f64::max) * 1.5;
    let lo = vals.fold(1.0f64, f64::min).min(0.8) * 0.8;
    (lo, hi)
}

/// Each rung's label at its x position: `k: paper + …` for the first, `k: + …` (the effects it
/// adds) for the others.
fn rung_labels(rungs: &[crate::diagnose::types::Rung]) -> Vec<(f64, String)> {
    rungs
        .iter()
        .enumerate()
        .map(|(k, g)| {
            let before = k.checked_sub(1).map(|j| rungs[j].model.as_slice());
            (k as f64, format!("{k}: {}", rung_name(&g.model, before)))
        })
        .collect()
}
/// Estimates shown per line under the ladder.
pub(super) const ESTIMATES_PER_LINE: usize = 4;

/// The estimates of each rung's added effects, value ± 1σ with the digits the 1σ calls for
/// ([`crate::format::pm`]), a few per line.
pub(super) fn ladder_estimates(rungs: &[crate::diagnose::types::Rung]) -> Vec<String> {
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
