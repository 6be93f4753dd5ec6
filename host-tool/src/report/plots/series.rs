//! The time-series figures: residual, innovations, whitened innovations, NIS.

use super::*;

/// A residual plot scales to its largest point when that is within this factor of the robust
/// range; a larger outlier (a glitch) would flatten the rest, so it is marked at the edge.
const SCALE_TO_DATA: f64 = 3.0;

/// The residual plot's half-range on `axis` and how many residuals lie below and above it: the
/// largest residual when it is within [`SCALE_TO_DATA`] times the robust range (99.5 %
/// quantile, at least 3.5 floors), else the robust range, the rest marked.
pub(super) fn residual_range(d: &Diagnosis, axis: usize) -> (f64, [usize; 2]) {
    let all = || d.series.residual.iter().map(move |r| r[axis]);
    let robust = (quantile(all().map(f64::abs), 0.995) * 1.15)
        .max(3.5 * d.floor_mps2[axis])
        .max(f64::MIN_POSITIVE);
    let max = all()
        .map(f64::abs)
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    let lim = if max <= SCALE_TO_DATA * robust {
        (max * 1.05).max(robust)
    } else {
        robust
    };
    (lim, count_beyond(all(), (-lim, lim)))
}

/// Residual (measured − predicted) with the ±1 and ±3 floor bands, each failure window on its
/// axis.
pub(super) fn residual<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    d: &Diagnosis,
) -> Result<()> {
    let s = &d.series;
    let x = x_range(&s.t_h);
    three_axes(area, x, |i| {
        let floor = d.floor_mps2[i];
        let (lim, beyond) = residual_range(d, i);
        let (f, unit) = scale(lim);
        Panel {
            caption: Some(format!(
                "{} axis: RMS/floor {:.2}",
                AXES[i], d.residual_rms_over_floor[i]
            )),
            y_desc: format!("residual, {unit}m/s²"),
            y: (-lim * f, lim * f),
            lines: vec![Line {
                label: Some("residual".into()),
                color: LINE,
                width: 1,
                dashed: false,
                pts: decimate(&s.t_h, |k| s.residual[k][i] * f, x, COLS),
            }],
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
            shade: shade_of(d, Some(i)),
            beyond: Some(beyond),
            legend: true,
            ..Panel::default()
        }
    })
}

pub(super) fn innovations<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    d: &Diagnosis,
) -> Result<()> {
    let s = &d.series;
    let x = x_range(&s.t_h);
    three_axes(area, x, |i| {
        // The first updates start from a wide prior: the range follows the typical 3σ band and
        // the bulk of the innovations, not the first few.
        let sig = quantile(s.innovation_sigma.iter().map(|v| v[i]), 0.5);
        let lim = (quantile(s.innovation.iter().map(|v| v[i].abs()), 0.99) * 1.15)
            .max(4.0 * sig)
            .max(f64::MIN_POSITIVE);
        let beyond = count_beyond(s.innovation.iter().map(|v| v[i]), (-lim, lim));
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
            shade: shade_of(d, Some(i)),
            beyond: Some(beyond),
            legend: true,
            ..Panel::default()
        }
    })
}

pub(super) fn whitened<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    d: &Diagnosis,
) -> Result<()> {
    let s = &d.series;
    let x = x_range(&s.t_h);
    three_axes(area, x, |i| {
        let lim = (quantile(s.whitened.iter().map(|v| v[i].abs()), 0.995) * 1.15).max(4.5);
        let beyond = count_beyond(s.whitened.iter().map(|v| v[i]), (-lim, lim));
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
            shade: shade_of(d, Some(i)),
            beyond: Some(beyond),
            legend: true,
            ..Panel::default()
        }
    })
}
/// A rolling NIS/3 mean ([`rolling_nis`]): points, window in updates, 95 % band.
type Rolled = (Vec<(f64, f64)>, usize, [f64; 2]);

/// The y range of the NIS/3 plot (log axis): from the rolling means, their band and, with
/// `raw`, the bulk of the single updates. NIS/3 spans decades (χ²(3)/3 of single updates reaches
/// down to 1e-3, a missing effect drives it to hundreds), and equal ratios around 1 look equal.
fn nis_range(s0: &Series, rolled: &[Rolled], raw: bool) -> (f64, f64) {
    let roll_hi = rolled
        .iter()
        .flat_map(|r| r.0.iter().map(|p| p.1))
        .fold(0.0f64, |a, b| if b.is_finite() { a.max(b) } else { a });
    let raw_q = if raw {
        quantile(s0.nis.iter().map(|v| v / 3.0), 0.995)
    } else {
        0.0
    };
    let top = (roll_hi * 1.3)
        .max(rolled[0].2[1] * 1.4)
        .max(raw_q)
        .max(2.0);
    // A log axis: NIS/3 spans decades (χ²(3)/3 of single updates reaches down to 1e-3, a
    // missing effect drives it to hundreds), and equal ratios around 1 look equal.
    let roll_lo = quantile(rolled.iter().flat_map(|r| r.0.iter().map(|p| p.1)), 0.01);
    let raw_lo = if raw {
        quantile(s0.nis.iter().map(|v| v / 3.0), 0.02)
    } else {
        f64::INFINITY
    };
    let bottom = (roll_lo * 0.8)
        .min(rolled[0].2[0] * 0.8)
        .min(raw_lo)
        .clamp(NIS_LOG_FLOOR, 0.5);
    (bottom, top)
}

/// NIS/3: for one diagnosis the raw values (faint) and the rolling mean with its band; for two,
/// the rolling means before and after.
pub(super) fn nis<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    ds: &[&Diagnosis],
    raw: bool,
) -> Result<()> {
    let s0 = &ds[0].series;
    let x = x_range(&s0.t_h);
    let rolled: Vec<_> = ds.iter().map(|d| rolling_nis(&d.series)).collect();
    let (_, w, band) = &rolled[0];
    let window_h = *w as f64 * period_h(&s0.t_h);
    let (bottom, top) = nis_range(s0, &rolled, raw);
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
                model_name(&d.model)
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
        shade: if raw { shade_of(ds[0], None) } else { vec![] },
        legend: true,
        ..Panel::default()
    };
    time_panel(area, x, &p)
}
