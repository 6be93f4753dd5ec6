//! The residual before and after, averaged over windows of about an hour: averaging takes the
//! white noise down by √n while a missing effect's slow signature stays, so a modest effect that
//! hides in the per-update noise shows here, and its removal by the final model too.

use super::*;

/// Means of `v` over consecutive windows of `w` updates of `t_h`: (window's middle time, mean).
/// A last partial window of fewer than `w / 2` updates is dropped (its mean is noisier than the
/// band drawn for the others).
pub(super) fn window_means(t_h: &[f64], v: impl Fn(usize) -> f64, w: usize) -> Vec<(f64, f64)> {
    let n = t_h.len();
    let w = w.max(1);
    (0..n)
        .step_by(w)
        .filter(|&a| n - a >= w.div_ceil(2))
        .map(|a| {
            let b = (a + w).min(n);
            let mean = (a..b).map(&v).sum::<f64>() / (b - a) as f64;
            (0.5 * (t_h[a] + t_h[b - 1]), mean)
        })
        .collect()
}

/// Before and after, per axis, as window means with ±3σ of a window mean of noise at the floor.
pub(super) fn residual_means<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    before: &Diagnosis,
    after: &Diagnosis,
) -> Result<()> {
    let s = &before.series;
    let x = x_range(&s.t_h);
    let (_, w, _) = rolling_nis(s);
    let window = hours_label(w as f64 * period_h(&s.t_h));
    three_axes(area, x, |i| {
        let mb = window_means(&s.t_h, |k| s.residual[k][i], w);
        let sa = &after.series;
        let ma = window_means(&sa.t_h, |k| sa.residual[k][i], w);
        let band = 3.0 * before.floor_mps2[i] / (w as f64).sqrt();
        let top = mb
            .iter()
            .chain(&ma)
            .map(|p| p.1.abs())
            .filter(|v| v.is_finite())
            .fold(band, f64::max)
            * 1.15;
        let (f, unit) = scale(top);
        let scaled = |m: Vec<(f64, f64)>| m.into_iter().map(|(t, v)| (t, v * f)).collect();
        Panel {
            caption: Some(format!(
                "{} axis: {window} means; RMS/floor of single updates {:.3} → {:.3}",
                AXES[i], before.residual_rms_over_floor[i], after.residual_rms_over_floor[i]
            )),
            y_desc: format!("{window} mean, {unit}m/s²"),
            y: (-top * f, top * f),
            hbands: vec![(
                -band * f,
                band * f,
                BAND3,
                Some(format!("±3σ of a {window} mean of noise at the floor")),
            )],
            lines: vec![
                Line {
                    label: Some(format!("before: {}", model_name(&before.model))),
                    color: BEFORE,
                    width: 2,
                    dashed: false,
                    pts: scaled(mb),
                },
                Line {
                    label: Some(format!("after: {}", model_name(&after.model))),
                    color: AFTER,
                    width: 2,
                    dashed: false,
                    pts: scaled(ma),
                },
            ],
            legend: true,
            ..Panel::default()
        }
    })
}
