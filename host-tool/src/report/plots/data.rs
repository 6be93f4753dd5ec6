//! Data helpers of the plots: decimation, robust ranges, rolling NIS, tick and unit labels.

use super::*;

/// Reduces a series to the minimum and maximum of each of `cols` columns over `x`, in time order.
/// Non-finite values are skipped.
pub(super) fn decimate(
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
pub(super) fn quantile(vals: impl Iterator<Item = f64>, q: f64) -> f64 {
    let mut v: Vec<f64> = vals.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let k = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    v[k]
}

pub(super) fn x_range(t: &[f64]) -> (f64, f64) {
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
pub(super) fn period_h(t: &[f64]) -> f64 {
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
pub(super) fn rolling_nis(s: &Series) -> (Vec<(f64, f64)>, usize, [f64; 2]) {
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
pub(super) fn scale(max_abs: f64) -> (f64, String) {
    if !(max_abs.is_finite() && max_abs > 0.0) {
        return (1.0, String::new());
    }
    let e = max_abs.log10().floor() as i32;
    if (-1..=3).contains(&e) {
        return (1.0, String::new());
    }
    (10f64.powi(-e), format!("10{} ", superscript(e)))
}

pub(super) fn superscript(e: i32) -> String {
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
pub(super) fn tick(v: f64) -> String {
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
pub(super) fn hours_label(h: f64) -> String {
    if (h - h.round()).abs() < 0.05 && h >= 1.0 {
        format!("{:.0}-h", h)
    } else if h >= 1.0 {
        format!("{h:.1}-h")
    } else {
        format!("{:.0}-min", h * 60.0)
    }
}
pub(super) fn minutes_label(h: f64) -> String {
    let s = h * 3600.0;
    if s >= 60.0 && (s / 60.0 - (s / 60.0).round()).abs() < 1e-6 {
        format!("{:.0} min each", s / 60.0)
    } else {
        format!("{} s each", tick(s))
    }
}
