//! Statistics of one model's residuals and innovations: whiteness (autocorrelation, Ljung–Box),
//! the time windows where the NIS leaves its band, the residual's correlation with candidate
//! regressors, and the summary numbers of a fit (RMS over the floor, mean NIS and its band).
//!
//! Every function here is a pure function of the series it is given; each is unit-tested against
//! reference values computed independently (numpy/scipy, statsmodels' definitions).

use super::types::{FailureWindow, RegressorCorrelation, Series};
pub use crate::consistency::whiteness;
use crate::stats::{chi2_quantile, normal_quantile};

/// χ² quantiles of the display band of the mean NIS/3, 95 % two-sided ([`Fit::nis_band95`]; the
/// band that decides consistency is [`crate::consistency::Thresholds::nis_band_prob`]'s).
pub(crate) const NIS_DISPLAY_QUANTILES: [f64; 2] = [0.025, 0.975];
/// Length of a failure-window block, h (a block is at least [`MIN_BLOCK_UPDATES`] updates).
pub(crate) const FAILURE_BLOCK_H: f64 = 1.0;
/// Fewest updates in a failure-window block.
pub(crate) const MIN_BLOCK_UPDATES: usize = 5;
/// χ² quantiles of the band (99 % two-sided) a block's mean NIS/3 must leave to be a failure
/// window.
pub(crate) const FAILURE_QUANTILES: [f64; 2] = [0.005, 0.995];
/// Normal quantile of the bound on a regressor correlation, 99 % two-sided
/// ([`RegressorCorrelation::bound99`]).
pub(crate) const CORRELATION_QUANTILE: f64 = 0.995;

/// The three axes' values of `f`.
pub(crate) fn per_axis<F: Fn(usize) -> f64>(f: F) -> [f64; 3] {
    [f(0), f(1), f(2)]
}

/// Summary numbers of one model against the measurements.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Fit {
    /// RMS of the residual along the converged trajectory, m/s², per axis.
    pub residual_rms_mps2: [f64; 3],
    /// RMS over the noise floor, per axis.
    pub residual_rms_over_floor: [f64; 3],
    /// Mean NIS/3.
    pub nis_mean: f64,
    /// [`NIS_DISPLAY_QUANTILES`] band of the mean NIS/3 for this many updates.
    pub nis_band95: [f64; 2],
}

/// RMS/floor, mean NIS/3 and its display band of a series against the noise floor;
/// `residual_rms_mps2` is the series' residual RMS on the floor's scale
/// ([`crate::identify::Prepared::residual_rms_mps2`], the one definition).
pub(crate) fn fit(s: &Series, floor_mps2: [f64; 3], residual_rms_mps2: [f64; 3]) -> Fit {
    let n_upd = s.residual.len();
    let residual_rms_over_floor = per_axis(|i| residual_rms_mps2[i] / floor_mps2[i]);
    let nis_mean = s.nis.iter().sum::<f64>() / (3.0 * n_upd as f64);
    let dof_nis = 3.0 * n_upd as f64;
    let nis_band95 = NIS_DISPLAY_QUANTILES.map(|q| chi2_quantile(q, dof_nis) / dof_nis);
    Fit {
        residual_rms_mps2,
        residual_rms_over_floor,
        nis_mean,
        nis_band95,
    }
}

/// [`FAILURE_BLOCK_H`] blocks whose mean NIS/3 leaves its [`FAILURE_QUANTILES`] band, merged into
/// intervals (adjacent blocks with the same worst axis).
pub(crate) fn failure_windows(s: &Series) -> Vec<FailureWindow> {
    let n = s.nis.len();
    if n < 2 {
        return vec![];
    }
    let dt_h = (s.t_h[n - 1] - s.t_h[0]) / (n - 1) as f64;
    let block = ((FAILURE_BLOCK_H / dt_h.max(1e-9)).round() as usize).max(MIN_BLOCK_UPDATES);
    let dof = 3.0 * block as f64;
    let [lo, hi] = FAILURE_QUANTILES.map(|q| chi2_quantile(q, dof) / dof);
    let mut out: Vec<FailureWindow> = vec![];
    let mut start = 0;
    while start + block <= n {
        let end = start + block;
        let nis = s.nis[start..end].iter().sum::<f64>() / dof;
        if nis < lo || nis > hi {
            push_window(&mut out, s, start..end, nis, dt_h);
        }
        start = end;
    }
    out
}

/// Appends the failing block `r` (mean NIS/3 `nis`) to `out`, merged with the last window when
/// it continues it on the same worst axis.
fn push_window(
    out: &mut Vec<FailureWindow>,
    s: &Series,
    r: std::ops::Range<usize>,
    nis: f64,
    dt_h: f64,
) {
    let ms = per_axis(|a| {
        s.whitened[r.clone()]
            .iter()
            .map(|w| w[a] * w[a])
            .sum::<f64>()
    });
    let worst = (0..3).max_by(|&a, &b| ms[a].total_cmp(&ms[b])).unwrap();
    let worst_axis = ['x', 'y', 'z'][worst];
    let (t0, t1) = (s.t_h[r.start], s.t_h[r.end - 1]);
    match out.last_mut() {
        Some(last) if (last.end_h - t0).abs() <= 1.5 * dt_h && last.worst_axis == worst_axis => {
            let w0 = last.end_h - last.start_h;
            let w1 = t1 - t0;
            last.nis_mean = (last.nis_mean * w0 + nis * w1) / (w0 + w1).max(1e-12);
            last.end_h = t1;
        }
        _ => out.push(FailureWindow {
            start_h: t0,
            end_h: t1,
            nis_mean: nis,
            worst_axis,
        }),
    }
}

/// The candidate regressors of the residual: specific-force components and their products (from
/// the prediction), time, and the temperature deviation when it varies.
pub(crate) fn regressors(s: &Series, temp_dev: &[f64]) -> Vec<(String, Vec<f64>)> {
    let a = |i: usize| s.predicted.iter().map(|p| p[i]).collect::<Vec<f64>>();
    let ab = |i: usize, k: usize| {
        s.predicted
            .iter()
            .map(|p| p[i] * p[k])
            .collect::<Vec<f64>>()
    };
    let mut regs: Vec<(String, Vec<f64>)> = vec![
        ("A_x".into(), a(0)),
        ("A_y".into(), a(1)),
        ("A_z".into(), a(2)),
        ("A_x*A_x".into(), ab(0, 0)),
        ("A_y*A_y".into(), ab(1, 1)),
        ("A_x*A_y".into(), ab(0, 1)),
        ("A_x*A_z".into(), ab(0, 2)),
        ("A_y*A_z".into(), ab(1, 2)),
        ("t".into(), s.t_h.clone()),
    ];
    if temp_dev.iter().any(|t| *t != 0.0) {
        regs.push(("temp".into(), temp_dev.to_vec()));
    }
    regs
}

/// Pearson correlation of `x` and `y` (0 when either is constant).
pub(crate) fn pearson(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len();
    let mx = x.iter().sum::<f64>() / n as f64;
    let my = y.iter().sum::<f64>() / n as f64;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for j in 0..n {
        sxy += (x[j] - mx) * (y[j] - my);
        sxx += (x[j] - mx).powi(2);
        syy += (y[j] - my).powi(2);
    }
    sxy / (sxx * syy).sqrt().max(1e-300)
}

/// Correlation of the smoothed residual of each axis with the candidate [`regressors`], with the
/// [`CORRELATION_QUANTILE`] bound for no correlation.
pub(crate) fn correlations(s: &Series, temp_dev: &[f64]) -> Vec<RegressorCorrelation> {
    let n = s.residual.len();
    let res: [Vec<f64>; 3] = [0, 1, 2].map(|i| s.residual.iter().map(|r| r[i]).collect());
    let bound99 = normal_quantile(CORRELATION_QUANTILE) / (n as f64).sqrt();
    regressors(s, temp_dev)
        .into_iter()
        .map(|(name, x)| RegressorCorrelation {
            regressor: name,
            corr: per_axis(|i| pearson(&x, &res[i])),
            bound99,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ljung_box_matches_the_reference_formula() {
        // 200 xorshift64 uniforms, the same on all three axes, 5 lags. Reference (numpy, the
        // statsmodels definition: biased ACF, Q = n(n+2)·Σ r_k²/(n−k)): Q = 6.4078950011973 per
        // axis, so 19.2236850035919 over three on 15 dof, p = 0.20377595747492616 (scipy
        // chi2.sf). Tolerances: 1e-9 relative (summation order only).
        let mut s: u64 = 0x9e3779b97f4a7c15;
        let w: Vec<[f64; 3]> = (0..200)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                let x = (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                [x, x, x]
            })
            .collect();
        let wh = whiteness(&w, 5);
        assert!(
            (wh.ljung_box_q - 19.223_685_003_591_9).abs() < 1e-9 * 19.2,
            "{}",
            wh.ljung_box_q
        );
        assert_eq!(wh.dof, 15.0);
        assert!(
            (wh.p_value - 0.203_775_957_474_926_16).abs() < 1e-9,
            "{}",
            wh.p_value
        );
    }

    /// `n` updates one minute apart with the given NIS and whitened innovations.
    fn series(nis: Vec<f64>, whitened: Vec<[f64; 3]>) -> Series {
        Series {
            t_h: (0..nis.len()).map(|j| j as f64 / 60.0).collect(),
            nis,
            whitened,
            ..Series::default()
        }
    }

    #[test]
    fn failure_windows_leave_the_chi2_band_and_merge() {
        // One-minute updates: one-hour blocks of 60, mean NIS/3 band on χ²(180)/180 at
        // 0.005/0.995: 0.74935805138422 – 1.292332226560257 (scipy.stats.chi2.ppf). Blocks:
        // 1.0 (in), 0.1 % above the top twice on axis x (one merged window), 0.1 % below the top
        // (in), 0.1 % below the bottom on axis z (a second window).
        let (lo, hi) = (0.749_358_051_384_22, 1.292_332_226_560_257);
        let levels = [1.0, hi * 1.001, hi * 1.001, hi * 0.999, lo * 0.999];
        let worst = [0, 0, 0, 1, 2];
        let mut nis = vec![];
        let mut w = vec![];
        for (b, level) in levels.iter().enumerate() {
            for _ in 0..60 {
                nis.push(3.0 * level);
                let mut v = [1.0; 3];
                v[worst[b]] = 2.0;
                w.push(v);
            }
        }
        let f = failure_windows(&series(nis, w));
        assert_eq!(f.len(), 2, "{f:?}");
        assert_eq!((f[0].start_h, f[0].end_h), (1.0, 179.0 / 60.0));
        assert_eq!(f[0].worst_axis, 'x');
        assert!((f[0].nis_mean - hi * 1.001).abs() < 1e-12);
        assert_eq!((f[1].start_h, f[1].end_h), (4.0, 299.0 / 60.0));
        assert_eq!(f[1].worst_axis, 'z');
        assert!((f[1].nis_mean - lo * 0.999).abs() < 1e-12);
    }

    #[test]
    fn correlations_match_numpy() {
        // 50 updates, A = (sin 0.3j, cos 0.2j + 0.1j, 1), residual per axis
        // (0.5 sin 0.3j + 0.01 j², cos 0.7j, (j mod 7) − 3). Reference: numpy.corrcoef with time
        // t = j/60 h and with A_x², and the bound scipy.stats.norm.ppf(0.995)/√50.
        let j: Vec<f64> = (0..50).map(|j| j as f64).collect();
        let s = Series {
            t_h: j.iter().map(|j| j / 60.0).collect(),
            predicted: j
                .iter()
                .map(|j| [(0.3 * j).sin(), (0.2 * j).cos() + 0.1 * j, 1.0])
                .collect(),
            residual: j
                .iter()
                .map(|j| {
                    [
                        0.5 * (0.3 * j).sin() + 0.01 * j * j,
                        (0.7 * j).cos(),
                        (j % 7.0) - 3.0,
                    ]
                })
                .collect(),
            ..Series::default()
        };
        let c = correlations(&s, &[0.0; 50]);
        let names: Vec<&str> = c.iter().map(|r| r.regressor.as_str()).collect();
        assert_eq!(
            names,
            ["A_x", "A_y", "A_z", "A_x*A_x", "A_y*A_y", "A_x*A_y", "A_x*A_z", "A_y*A_z", "t"]
        );
        let t_ref = [
            0.961_312_645_239_002_1,
            -0.038_429_275_059_895_56,
            0.083_882_699_920_215_27,
        ];
        let xx_ref = [
            0.126_699_644_591_913_24,
            0.155_540_016_276_976_42,
            0.123_553_647_187_049_31,
        ];
        for i in 0..3 {
            assert!((c[8].corr[i] - t_ref[i]).abs() < 1e-12, "{:?}", c[8].corr);
            assert!((c[3].corr[i] - xx_ref[i]).abs() < 1e-12, "{:?}", c[3].corr);
        }
        // A constant regressor correlates with nothing.
        assert_eq!(c[2].corr, [0.0; 3]);
        assert!((c[0].bound99 - 0.364_277_273_543_689_9).abs() < 1e-8);
        // A varying temperature joins the regressors.
        let temp: Vec<f64> = j.iter().map(|j| 0.1 * j).collect();
        let c = correlations(&s, &temp);
        assert_eq!(c.last().unwrap().regressor, "temp");
        assert!((c.last().unwrap().corr[0] - t_ref[0]).abs() < 1e-12);
    }

    #[test]
    fn fit_summarises_against_the_floor() {
        // 30 updates with residual (2, 1, 0.5)·floor and NIS 3.3: RMS/floor (2, 1, 0.5), mean
        // NIS/3 1.1, band χ²(90)/90 at 0.025/0.975 = 0.7294068619607659 – 1.312621028451283
        // (scipy.stats.chi2.ppf).
        let floor = [1e-4, 2e-4, 4e-4];
        let s = Series {
            residual: vec![[2e-4, 2e-4, 2e-4]; 30],
            nis: vec![3.3; 30],
            ..Series::default()
        };
        let rms = crate::identify::rms_per_axis(&s.residual, |_, _| 1.0);
        let f = fit(&s, floor, rms);
        for (got, want) in f.residual_rms_over_floor.iter().zip([2.0, 1.0, 0.5]) {
            assert!(
                (got - want).abs() < 1e-12,
                "{:?}",
                f.residual_rms_over_floor
            );
        }
        assert!((f.nis_mean - 1.1).abs() < 1e-12);
        assert!((f.nis_band95[0] - 0.729_406_861_960_765_9).abs() < 1e-9);
        assert!((f.nis_band95[1] - 1.312_621_028_451_283).abs() < 1e-9);
    }
}
