//! Model against measurements: where the model fails, which physical effect is missing, and the
//! ladder that adds it and watches the error fall.
//!
//! On the converged identification of a model (never a single pass: its residuals sit far above
//! the floor even on clean data) we compute
//! - the residual along the smoothed trajectory against the noise floor estimated from the raw
//!   samples themselves, and the innovations of one replay of the final forward pass with their
//!   NIS and whitened values;
//! - whiteness (autocorrelation, Ljung–Box), the time windows where the NIS leaves its band, and
//!   the correlation of the residual with candidate regressors;
//! - a score test per catalog effect not in the model ([`score`]), from that one replay;
//! - how alike the leading candidates' signatures are (canonical correlation).

pub mod score;
pub mod select;
pub mod types;
pub mod wander;

use estimator_core::effects::Effect;
use estimator_core::model::MAX_STATES;
use estimator_core::units::S_PER_H;
use estimator_core::Model;

use self::score::{canonical_correlation, signatures, Signature};
pub use self::types::*;
use self::wander::DriftWander;
use crate::catalog;
use crate::cli::common::build_model;
use crate::consistency::{assess, Thresholds};
use crate::identify::smoother::temp_devs;
use crate::identify::{identify, smoothed_residuals, wide_prior, Config, Identification, Prepared};
use crate::stats::{chi2_ln_sf, chi2_quantile, chi2_sf, normal_quantile};

/// Statistic gap below which two similar candidates are "not clearly separated": a likelihood
/// ratio below e^5 ≈ 150 : 1.
pub const SEPARATION_GAP: f64 = 10.0;

/// Settings of a diagnosis.
#[derive(Clone, Debug)]
pub struct DiagnoseConfig {
    /// Identification settings.
    pub identify: Config,
    /// Significance level of the candidate tests (after Holm's adjustment).
    pub alpha: f64,
    /// Lags of the Ljung–Box test.
    pub lags: usize,
    /// Longest ladder (models tried, the first included).
    pub max_rungs: usize,
    /// Correlation time of the Gauss–Markov stand-in blocks, h.
    pub markov_block_h: f64,
}

impl Default for DiagnoseConfig {
    fn default() -> Self {
        DiagnoseConfig {
            identify: Config::default(),
            alpha: 0.01,
            lags: 20,
            max_rungs: 4,
            markov_block_h: 5.0,
        }
    }
}

fn per_axis<F: Fn(usize) -> f64>(f: F) -> [f64; 3] {
    [f(0), f(1), f(2)]
}

fn separate_by(a: &str, b: &str) -> String {
    let accel = |e: &str| e.starts_with("acc-");
    let slow = |e: &str| matches!(e, "g2" | "drift-trend" | "drift-markov");
    if accel(a) && accel(b) {
        "another initial platform orientation or a second run at another latitude: bias, scale factor and misalignment project differently onto the gravity cone".into()
    } else if a == "temp-drift" || b == "temp-drift" {
        "a temperature excursion that is not synchronised with the gravity cone (e.g. a heater step mid-run)".into()
    } else if slow(a) && slow(b) {
        "a longer run: a trend keeps growing while g²-sensitive drift repeats with the sidereal day; another initial orientation also changes the g² signature".into()
    } else {
        "a longer run, or another latitude or initial platform orientation".into()
    }
}

struct CandidateSetup {
    name: &'static str,
    about: &'static str,
    effect: Option<Box<dyn Effect>>,
    catalog: Option<&'static dyn Effect>,
    untestable: Option<String>,
}

/// Diagnoses one model (the paper's drift plus `effects`) on prepared measurements.
pub fn diagnose(
    prep: &Prepared,
    effects: &[&'static dyn Effect],
    cfg: &DiagnoseConfig,
) -> anyhow::Result<(Diagnosis, Identification)> {
    let model = build_model(prep.site, effects, &cfg.identify)?;
    let id = identify(&model, prep, &cfg.identify)?;
    anyhow::ensure!(
        !id.trajectory.is_empty(),
        "diagnosis needs the converged identification (smoother iterations > 0)"
    );
    let meas = &prep.measurements;
    let n = model.dim();
    let run_s = meas.last().map(|m| m.t_s).unwrap_or(0.0);
    let has_temp = {
        let t: Vec<f64> = meas
            .iter()
            .map(|m| m.temp_c)
            .filter(|t| t.is_finite())
            .collect();
        t.len() > 1
            && t.iter().cloned().fold(f64::MIN, f64::max)
                - t.iter().cloned().fold(f64::MAX, f64::min)
                > 1e-6
    };
    // Candidates: every catalog effect not in the model.
    let mut setups: Vec<CandidateSetup> = vec![];
    for c in catalog::candidates() {
        if effects.iter().any(|e| e.name() == c.name()) {
            continue;
        }
        let mut s = CandidateSetup {
            name: c.name(),
            about: c.about(),
            effect: None,
            catalog: Some(c),
            untestable: None,
        };
        if c.name() == "temp-drift" && !has_temp {
            s.untestable = Some("the recording has no varying temp_c column".into());
        } else if c.name() == "drift-markov" {
            let room = (MAX_STATES - n) / 3;
            if room == 0 {
                s.untestable = Some("no room left in the state".into());
            } else {
                s.effect = Some(Box::new(DriftWander::new(
                    cfg.markov_block_h * S_PER_H,
                    run_s.max(1.0),
                    room,
                )));
            }
        } else if n + c.params().len() > MAX_STATES {
            s.untestable = Some(format!(
                "the extended model would exceed {MAX_STATES} states"
            ));
        }
        setups.push(s);
    }
    let lists: Vec<Option<Vec<&dyn Effect>>> = setups
        .iter()
        .map(|s| {
            if s.untestable.is_some() {
                return None;
            }
            let e: &dyn Effect = match &s.effect {
                Some(b) => b.as_ref(),
                None => s.catalog.unwrap(),
            };
            let mut v: Vec<&dyn Effect> = effects.to_vec();
            v.push(e);
            Some(v)
        })
        .collect();
    let extended: Vec<Option<Model<'_>>> = lists
        .iter()
        .map(|l| {
            l.as_ref()
                .and_then(|l| build_model(prep.site, l, &cfg.identify).ok())
        })
        .collect();
    let mut x0 = vec![0.0; n];
    x0[..3].copy_from_slice(&prep.initial_angles);
    let (x0, p0) = wide_prior(&model, &x0, &prep.initial_angle_sigma);
    let (pass, sigs, _) = signatures(&model, &extended, meas, &id.trajectory, &x0, &p0)?;

    // Series and residual statistics.
    let residual = smoothed_residuals(&model, meas, &id.trajectory);
    let n_upd = meas.len();
    let series = Series {
        t_h: meas.iter().map(|m| m.t_s / S_PER_H).collect(),
        measured: meas.iter().map(|m| m.specific_force).collect(),
        predicted: meas
            .iter()
            .zip(&residual)
            .map(|(m, r)| per_axis(|i| m.specific_force[i] - r[i]))
            .collect(),
        residual: residual.clone(),
        innovation: pass.innovations.iter().map(|r| r.innovation).collect(),
        innovation_sigma: pass
            .innovations
            .iter()
            .map(|r| per_axis(|i| r.s[i][i].sqrt()))
            .collect(),
        whitened: pass.innovations.iter().map(|r| r.whitened).collect(),
        nis: pass.innovations.iter().map(|r| r.nis).collect(),
    };
    let floor_mps2 = prep.floor_mps2();
    let residual_rms_mps2 =
        per_axis(|i| (residual.iter().map(|r| r[i] * r[i]).sum::<f64>() / n_upd as f64).sqrt());
    let residual_rms_over_floor = per_axis(|i| residual_rms_mps2[i] / floor_mps2[i]);
    let nis_mean = series.nis.iter().sum::<f64>() / (3.0 * n_upd as f64);
    let dof_nis = 3.0 * n_upd as f64;
    let nis_band95 = [
        chi2_quantile(0.025, dof_nis) / dof_nis,
        chi2_quantile(0.975, dof_nis) / dof_nis,
    ];
    let whiteness = whiteness(&series.whitened, cfg.lags);
    let failures = failure_windows(&series);
    let correlations = correlations(&series, &temp_devs(meas));

    // Candidates.
    let tested = sigs.iter().filter(|s| s.is_some()).count().max(1);
    let mut ranking: Vec<(Candidate, Option<&Signature>)> = setups
        .iter()
        .zip(&sigs)
        .map(|(s, sig)| match sig {
            None => (
                Candidate {
                    effect: s.name.into(),
                    about: s.about.into(),
                    statistic: f64::NAN,
                    dof: 0.0,
                    p_value: f64::NAN,
                    p_adjusted: f64::NAN,
                    ln_p_value: f64::NAN,
                    ln_p_adjusted: f64::NAN,
                    params: vec![],
                    refit: None,
                    untestable: s
                        .untestable
                        .clone()
                        .or(Some("extended model could not be built".into())),
                },
                None,
            ),
            Some(sig) => {
                let t = sig.test();
                let ln_p_value = if t.dof > 0 {
                    chi2_ln_sf(t.statistic, t.dof as f64)
                } else {
                    0.0
                };
                let p_value = ln_p_value.exp();
                let lambda = noncentrality_for_power(t.dof.max(1) as f64, cfg.alpha, 0.9);
                let e: &dyn Effect = match &s.effect {
                    Some(b) => b.as_ref(),
                    None => s.catalog.unwrap(),
                };
                let params = e
                    .params()
                    .iter()
                    .enumerate()
                    .map(|(k, p)| ParamEstimate {
                        name: p.name.into(),
                        unit: p.unit.into(),
                        value: t.estimate[k],
                        sigma: t.cov[(k, k)].max(0.0).sqrt(),
                        min_detectable: if sig.info[(k, k)] > 0.0 {
                            (lambda / sig.info[(k, k)]).sqrt()
                        } else {
                            f64::INFINITY
                        },
                    })
                    .collect();
                (
                    Candidate {
                        effect: s.name.into(),
                        about: s.about.into(),
                        statistic: t.statistic,
                        dof: t.dof as f64,
                        p_value,
                        p_adjusted: p_value,
                        ln_p_value,
                        ln_p_adjusted: ln_p_value,
                        params,
                        refit: None,
                        untestable: None,
                    },
                    Some(sig),
                )
            }
        })
        .collect();
    ranking.sort_by(
        |a, b| match (a.0.untestable.is_some(), b.0.untestable.is_some()) {
            (false, true) => std::cmp::Ordering::Less,
            (true, false) => std::cmp::Ordering::Greater,
            _ => {
                a.0.ln_p_value
                    .total_cmp(&b.0.ln_p_value)
                    .then(a.0.dof.total_cmp(&b.0.dof))
            }
        },
    );
    // Holm's step-down adjustment over the tested candidates, in logs (no underflow).
    let mut running = f64::NEG_INFINITY;
    for (rank, (c, _)) in ranking
        .iter_mut()
        .filter(|(c, _)| c.untestable.is_none())
        .enumerate()
    {
        running = running.max((((tested - rank) as f64).ln() + c.ln_p_value).min(0.0));
        c.ln_p_adjusted = running;
        c.p_adjusted = running.exp();
    }
    // Confounding among the leading candidates.
    let mut confounding = vec![];
    let leaders: Vec<usize> = (0..ranking.len().min(4))
        .filter(|&k| ranking[k].1.is_some())
        .collect();
    for (ai, &a) in leaders.iter().enumerate() {
        for &b in &leaders[ai + 1..] {
            let cc = canonical_correlation(ranking[a].1.unwrap(), ranking[b].1.unwrap());
            let significant =
                ranking[a].0.p_adjusted < cfg.alpha || ranking[b].0.p_adjusted < cfg.alpha;
            if cc > 0.9 && significant {
                confounding.push(Confounding {
                    a: ranking[a].0.effect.clone(),
                    b: ranking[b].0.effect.clone(),
                    canonical_correlation: cc,
                    statistic_gap: ranking[a].0.statistic - ranking[b].0.statistic,
                    separated: (ranking[a].0.statistic - ranking[b].0.statistic).abs()
                        >= SEPARATION_GAP,
                    separate_by: separate_by(&ranking[a].0.effect, &ranking[b].0.effect),
                });
            }
        }
    }
    let mut ranking: Vec<Candidate> = ranking.into_iter().map(|(c, _)| c).collect();
    // The leading significant candidates refitted; the evidence chooses among them.
    let leaders: Vec<String> = ranking
        .iter()
        .filter(|c| c.untestable.is_none() && c.p_adjusted < cfg.alpha)
        .take(select::REFIT_LEADERS)
        .map(|c| c.effect.clone())
        .collect();
    let base_evidence = select::neg2_log_evidence(&id);
    let refits = select::refit(prep, effects, base_evidence, &leaders, cfg);
    for r in &refits {
        if let Some(c) = ranking.iter_mut().find(|c| c.effect == r.effect) {
            c.refit = Some(r.clone());
        }
    }
    let choice = select::choose(&refits);
    let consistency = assess(
        nis_mean,
        n_upd,
        whiteness.p_value,
        residual_rms_over_floor,
        prep.floor_rel_sd(),
        &Thresholds::default(),
    );
    let model_names: Vec<String> = effects
        .iter()
        .filter(|e| e.name() != "paper")
        .map(|e| e.name().to_string())
        .collect();
    let mut d = Diagnosis {
        model: model_names,
        floor_mps2,
        residual_rms_mps2,
        residual_rms_over_floor,
        nis_mean,
        nis_band95,
        whiteness,
        failures,
        correlations,
        ranking,
        confounding,
        consistency,
        choice,
        verdict: String::new(),
        series,
    };
    d.verdict = verdict(&d, cfg.alpha);
    Ok((d, id))
}

/// Whether the model explains the data: the one definition ([`crate::consistency`]).
pub fn is_consistent(d: &Diagnosis) -> bool {
    d.consistency.is_consistent()
}

fn verdict(d: &Diagnosis, alpha: f64) -> String {
    let rms: Vec<String> = d
        .residual_rms_over_floor
        .iter()
        .map(|r| format!("{r:.2}"))
        .collect();
    let state = format!(
        "Residual RMS / noise floor = [{}] (x, y, z), mean NIS/3 = {:.3} (99.9 % band {:.3}–{:.3}), Ljung–Box p = {:.2e}.",
        rms.join(", "),
        d.nis_mean,
        d.consistency.nis_band[0],
        d.consistency.nis_band[1],
        d.whiteness.p_value
    );
    if let Some(choice) = &d.choice {
        let c = d.ranking.iter().find(|c| c.effect == choice.effect);
        let mut s = format!(
            "{state} The model misses a physical effect: {}.",
            choice.reason
        );
        if let Some(r) = c.and_then(|c| c.refit.as_ref()) {
            s += &format!(
                " With it the residual RMS / floor is [{:.2}, {:.2}, {:.2}], NIS/3 {:.3}, Ljung–Box p {:.1e} ({}).",
                r.rms_over_floor[0],
                r.rms_over_floor[1],
                r.rms_over_floor[2],
                r.nis_mean,
                r.whiteness_p,
                if r.consistent { "consistent" } else { "still not consistent" }
            );
        }
        if let Some(c) = c {
            s += &format!(" {}", c.about);
            for cf in d
                .confounding
                .iter()
                .filter(|cf| !cf.separated && (cf.a == c.effect || cf.b == c.effect))
            {
                let rival = if cf.a == c.effect { &cf.b } else { &cf.a };
                s += &format!(
                    " Caution: `{rival}` leaves almost the same signature on this run (canonical correlation {:.3}); the data barely separate them. What would: {}.",
                    cf.canonical_correlation, cf.separate_by
                );
            }
        }
        return s;
    }
    if is_consistent(d) {
        return format!(
            "{state} The model explains the measurements: the residual is at the noise floor, white and consistent with its covariance; no catalog effect earns its place (score tests at {:.0} %, refits by evidence).",
            alpha * 100.0
        );
    }
    let why = d.consistency.failures.join("; ");
    let corr: Vec<String> = d
        .correlations
        .iter()
        .filter_map(|c| {
            let m = c.corr.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            (m > c.bound99).then(|| format!("{} ({:+.2})", c.regressor, m))
        })
        .collect();
    let windows: Vec<String> = d
        .failures
        .iter()
        .take(5)
        .map(|f| format!("{:.1}–{:.1} h (axis {})", f.start_h, f.end_h, f.worst_axis))
        .collect();
    format!(
        "{state} OUTSIDE THE CATALOG: the model does not explain the measurements ({why}), and no catalog effect improves it enough to earn its place. \
         The residual still correlates with: {}; it fails most in: {}. Define the missing effect in a file \
         (`--effects FILE.toml`, README \"Effects defined in a file\") as an expression of A_x, A_y, A_z, t_h, temp_c and its parameters, and diagnose again.",
        if corr.is_empty() { "none of the regressors beyond chance".to_string() } else { corr.join(", ") },
        if windows.is_empty() { "no particular window".to_string() } else { windows.join(", ") }
    )
}

/// Smallest noncentrality λ of χ²(k, λ) that exceeds the level-`alpha` critical value with
/// probability `power` (Patnaik's two-moment approximation, bisection).
pub fn noncentrality_for_power(k: f64, alpha: f64, power: f64) -> f64 {
    let crit = chi2_quantile(1.0 - alpha, k);
    let pw = |l: f64| {
        let h = (k + l).powi(2) / (k + 2.0 * l);
        let scale = (k + 2.0 * l) / (k + l);
        chi2_sf(crit / scale, h)
    };
    let (mut lo, mut hi) = (0.0, 1e4);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if pw(mid) < power {
            lo = mid
        } else {
            hi = mid
        }
    }
    hi
}

/// Autocorrelation of each axis' whitened innovations and the Ljung–Box test over the three axes.
///
/// The whitened innovations of a filter are white under its model by construction (they are not
/// residuals of a fit), so the Ljung–Box statistic is referred to χ²(3m) without the reduction
/// for fitted ARMA parameters; the 12+ fitted constants shift the innovations by O(1/N).
pub fn whiteness(w: &[[f64; 3]], lags: usize) -> Whiteness {
    let n = w.len();
    let lags = lags.min(n.saturating_sub(2)).max(1);
    let mut acf = vec![[0.0; 3]; lags];
    let mut q = 0.0;
    for a in 0..3 {
        let mean = w.iter().map(|x| x[a]).sum::<f64>() / n as f64;
        let var = w.iter().map(|x| (x[a] - mean).powi(2)).sum::<f64>();
        for k in 1..=lags {
            let c: f64 = (k..n)
                .map(|j| (w[j][a] - mean) * (w[j - k][a] - mean))
                .sum();
            let r = c / var.max(1e-300);
            acf[k - 1][a] = r;
            q += r * r / (n - k) as f64;
        }
    }
    let q = n as f64 * (n as f64 + 2.0) * q;
    let dof = 3.0 * lags as f64;
    Whiteness {
        acf,
        acf_bound95: 1.96 / (n as f64).sqrt(),
        ljung_box_q: q,
        dof,
        p_value: chi2_sf(q, dof),
    }
}

/// One-hour blocks whose mean NIS/3 leaves its 99 % band, merged into intervals.
pub fn failure_windows(s: &Series) -> Vec<FailureWindow> {
    let n = s.nis.len();
    if n < 2 {
        return vec![];
    }
    let dt_h = (s.t_h[n - 1] - s.t_h[0]) / (n - 1) as f64;
    let block = ((1.0 / dt_h.max(1e-9)).round() as usize).max(5);
    let dof = 3.0 * block as f64;
    let (lo, hi) = (
        chi2_quantile(0.005, dof) / dof,
        chi2_quantile(0.995, dof) / dof,
    );
    let mut out: Vec<FailureWindow> = vec![];
    let mut start = 0;
    while start + block <= n {
        let end = start + block;
        let nis = s.nis[start..end].iter().sum::<f64>() / dof;
        if nis < lo || nis > hi {
            let ms = per_axis(|a| {
                s.whitened[start..end]
                    .iter()
                    .map(|w| w[a] * w[a])
                    .sum::<f64>()
            });
            let worst = (0..3).max_by(|&a, &b| ms[a].total_cmp(&ms[b])).unwrap();
            let (t0, t1) = (s.t_h[start], s.t_h[end - 1]);
            match out.last_mut() {
                Some(last)
                    if (last.end_h - t0).abs() <= 1.5 * dt_h
                        && last.worst_axis == ['x', 'y', 'z'][worst] =>
                {
                    let w0 = last.end_h - last.start_h;
                    let w1 = t1 - t0;
                    last.nis_mean = (last.nis_mean * w0 + nis * w1) / (w0 + w1).max(1e-12);
                    last.end_h = t1;
                }
                _ => out.push(FailureWindow {
                    start_h: t0,
                    end_h: t1,
                    nis_mean: nis,
                    worst_axis: ['x', 'y', 'z'][worst],
                }),
            }
        }
        start = end;
    }
    out
}

/// Correlation of the smoothed residual of each axis with candidate regressors.
pub fn correlations(s: &Series, temp_dev: &[f64]) -> Vec<RegressorCorrelation> {
    let n = s.residual.len();
    let a = |j: usize, i: usize| s.predicted[j][i];
    let mut regs: Vec<(String, Vec<f64>)> = vec![
        ("A_x".into(), (0..n).map(|j| a(j, 0)).collect()),
        ("A_y".into(), (0..n).map(|j| a(j, 1)).collect()),
        ("A_z".into(), (0..n).map(|j| a(j, 2)).collect()),
        (
            "A_x*A_x".into(),
            (0..n).map(|j| a(j, 0) * a(j, 0)).collect(),
        ),
        (
            "A_y*A_y".into(),
            (0..n).map(|j| a(j, 1) * a(j, 1)).collect(),
        ),
        (
            "A_x*A_y".into(),
            (0..n).map(|j| a(j, 0) * a(j, 1)).collect(),
        ),
        (
            "A_x*A_z".into(),
            (0..n).map(|j| a(j, 0) * a(j, 2)).collect(),
        ),
        (
            "A_y*A_z".into(),
            (0..n).map(|j| a(j, 1) * a(j, 2)).collect(),
        ),
        ("t".into(), s.t_h.clone()),
    ];
    if temp_dev.iter().any(|t| *t != 0.0) {
        regs.push(("temp".into(), temp_dev.to_vec()));
    }
    let corr = |x: &[f64], y: &[f64]| {
        let mx = x.iter().sum::<f64>() / n as f64;
        let my = y.iter().sum::<f64>() / n as f64;
        let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
        for j in 0..n {
            sxy += (x[j] - mx) * (y[j] - my);
            sxx += (x[j] - mx).powi(2);
            syy += (y[j] - my).powi(2);
        }
        sxy / (sxx * syy).sqrt().max(1e-300)
    };
    let res: [Vec<f64>; 3] = [0, 1, 2].map(|i| s.residual.iter().map(|r| r[i]).collect());
    let bound99 = normal_quantile(0.995) / (n as f64).sqrt();
    regs.into_iter()
        .map(|(name, x)| RegressorCorrelation {
            regressor: name,
            corr: per_axis(|i| corr(&x, &res[i])),
            bound99,
        })
        .collect()
}

/// What the model ladder produces.
pub struct Ladder {
    /// Every rung's diagnosis, the starting model first.
    pub diagnoses: Vec<Diagnosis>,
    /// The rung summaries (the same order).
    pub rungs: Vec<Rung>,
    /// The final model's identification.
    pub identification: Identification,
    /// The final model's effects (the paper's drift first).
    pub effects: Vec<&'static dyn Effect>,
}

/// The model ladder: start from `start` effects, diagnose, add the effect the evidence chooses,
/// repeat until nothing earns its place (or `max_rungs`).
pub fn ladder(
    prep: &Prepared,
    start: &[&'static dyn Effect],
    cfg: &DiagnoseConfig,
) -> anyhow::Result<Ladder> {
    let mut effects = start.to_vec();
    let mut diagnoses = vec![];
    let mut rungs: Vec<Rung> = vec![];
    loop {
        let (d, id) = diagnose(prep, &effects, cfg)?;
        let best = id.best();
        let coefficients = id
            .params
            .iter()
            .take(12)
            .enumerate()
            .map(|(k, p)| (p.name.to_string(), best.value[k], best.sigma(k)))
            .collect();
        let effect_params = id
            .params
            .iter()
            .enumerate()
            .skip(12)
            .map(|(k, p)| {
                (
                    p.name.to_string(),
                    p.unit.to_string(),
                    best.value[k],
                    best.sigma(k),
                )
            })
            .collect();
        let choice = d.choice.clone();
        rungs.push(Rung {
            model: d.model.clone(),
            residual_rms_over_floor: d.residual_rms_over_floor,
            nis_mean: d.nis_mean,
            whiteness_p: d.whiteness.p_value,
            coefficients,
            effect_params,
            consistent: is_consistent(&d),
            next: None,
            next_reason: None,
        });
        let p_of = |name: &str| {
            d.ranking
                .iter()
                .find(|c| c.effect == name)
                .map(|c| c.p_adjusted)
                .unwrap_or(f64::NAN)
        };
        let next = match &choice {
            Some(c) if rungs.len() < cfg.max_rungs => {
                catalog::by_name(&c.effect).map(|e| (e, p_of(&c.effect), c.reason.clone()))
            }
            _ => None,
        };
        diagnoses.push(d);
        match next {
            Some((e, p, reason)) => {
                if let Some(last) = rungs.last_mut() {
                    last.next = Some((e.name().to_string(), p));
                    last.next_reason = Some(reason);
                }
                effects.push(e);
            }
            None => {
                return Ok(Ladder {
                    diagnoses,
                    rungs,
                    identification: id,
                    effects,
                })
            }
        }
    }
}

#[cfg(test)]
mod whiteness_tests {
    use super::whiteness;

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
}
