//! The residual's correlation with candidate regressors.

use super::*;

pub(super) fn correlations<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    d: &Diagnosis,
) -> Result<()> {
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
        .label_style((FONT, 14))
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
