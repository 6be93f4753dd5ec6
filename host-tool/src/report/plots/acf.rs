//! The autocorrelation of the whitened innovations.

use super::*;

pub(super) fn acf<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, d: &Diagnosis) -> Result<()> {
    let wh = &d.whiteness;
    let (cap, rest) = area.split_vertically(24);
    cap.draw(&Text::new(
        format!(
            "Ljung–Box Q = {:.1} on {:.0} dof (three axes), p = {}; dashed: ±1.96/√N = ±{:.3} (95 % bound of a white sequence); red: a lag beyond it",
            wh.ljung_box_q,
            wh.dof,
            fmt_p(wh.p_value),
            wh.acf_bound95
        ),
        (80, 4),
        (FONT, 14),
    ))
    .map_err(err)?;
    let lim = wh
        .acf
        .iter()
        .flat_map(|a| a.iter().map(|v| v.abs()))
        .fold(0.0f64, |a, b| if b.is_finite() { a.max(b) } else { a })
        .max(2.0 * wh.acf_bound95)
        .max(0.05)
        * 1.1;
    for (i, a) in rest.split_evenly((1, 3)).iter().enumerate() {
        acf_axis(a, d, i, lim)?;
    }
    Ok(())
}

/// The stems of axis `i` within ±`lim`, the 95 % bound shaded and dashed.
fn acf_axis<DB: DrawingBackend>(
    a: &DrawingArea<DB, Shift>,
    d: &Diagnosis,
    i: usize,
    lim: f64,
) -> Result<()> {
    let wh = &d.whiteness;
    let m = wh.acf.len();
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
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 14))
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
    draw_stems(&mut chart, d, i, lim)
}

/// The stems of axis `i`, clamped to ±`lim`: red beyond the 95 % bound, else one neutral colour.
fn draw_stems<DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    d: &Diagnosis,
    i: usize,
    lim: f64,
) -> Result<()> {
    let wh = &d.whiteness;
    let b = wh.acf_bound95;
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
            // Red only beyond the bound; the axes' own colours (orange for y) read as
            // red on the page.
            let color = if v.abs() > b { RED } else { LINE };
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
    Ok(())
}
