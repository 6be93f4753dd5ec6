//! The candidates: every catalog effect not in the model, scored by the score tests of one
//! replay ([`super::score`]), ranked by log p-value (Holm-adjusted), and the confounded pairs
//! among the leaders.

use estimator_core::effects::Effect;
use estimator_core::model::MAX_STATES;
use estimator_core::units::S_PER_H;

use super::score::{canonical_correlation, footprint, Signature};
use super::types::{Candidate, Confounding, ParamEstimate};
use super::wander::DriftWander;
use super::DiagnoseConfig;
use crate::catalog::Catalog;
use crate::stats::{chi2_ln_sf, chi2_quantile, chi2_sf};

/// Gap of −2 ln p below which two similar candidates are "not clearly separated": a ratio of
/// p-values below e^5 ≈ 150 : 1.
pub(crate) const SEPARATION_GAP: f64 = 10.0;
/// Canonical correlation above which two candidates' signatures count as confounded.
pub(crate) const CONFOUNDING_CORRELATION: f64 = 0.9;
/// How many of the leading candidates are compared for confounding.
pub(crate) const CONFOUNDING_LEADERS: usize = 4;
/// Power at which [`ParamEstimate::min_detectable`] is quoted.
pub(crate) const DETECTION_POWER: f64 = 0.9;

/// One catalog effect as a candidate for this model: the effect scored (the catalog's, or a
/// stand-in built for this run), or why it cannot be tested.
pub(crate) struct Setup<'c> {
    /// Catalog name.
    pub name: &'c str,
    /// Physical explanation.
    pub about: &'c str,
    /// A stand-in built for this run (`drift-markov`'s piecewise-constant blocks).
    pub effect: Option<Box<dyn Effect>>,
    /// The catalog's effect.
    pub catalog: Option<&'c dyn Effect>,
    /// Why it cannot be tested here.
    pub untestable: Option<String>,
}

impl Setup<'_> {
    /// The effect that is scored (the stand-in when there is one).
    pub(crate) fn scored(&self) -> &dyn Effect {
        match &self.effect {
            Some(b) => b.as_ref(),
            None => self.catalog.unwrap(),
        }
    }
}

/// Every catalog effect not among `effects`, set up for a model of `dim` states over a run of
/// `run_s` seconds; `has_temp`: the recording has a varying temperature.
pub(crate) fn setups<'c>(
    catalog: &'c Catalog,
    effects: &[&dyn Effect],
    dim: usize,
    run_s: f64,
    has_temp: bool,
    cfg: &DiagnoseConfig,
) -> Vec<Setup<'c>> {
    let mut out = vec![];
    for c in catalog.candidates() {
        if effects.iter().any(|e| e.name() == c.name()) {
            continue;
        }
        let mut s = Setup {
            name: c.name(),
            about: c.about(),
            effect: None,
            catalog: Some(c),
            untestable: None,
        };
        if c.reads_temperature() && !has_temp {
            s.untestable = Some("the recording has no varying temp_c column".into());
        } else if c.name() == "drift-markov" {
            let room = (MAX_STATES - dim) / 3;
            if room == 0 {
                s.untestable = Some("no room left in the state".into());
            } else {
                let block_s = cfg.markov_block_h * S_PER_H;
                s.effect = Some(Box::new(DriftWander::new(block_s, run_s.max(1.0), room)));
            }
        } else if dim + c.params().len() > MAX_STATES {
            s.untestable = Some(format!(
                "the extended model would exceed {MAX_STATES} states"
            ));
        }
        out.push(s);
    }
    out
}

/// The model's effects followed by each testable candidate's (`None`: untestable).
pub(crate) fn extended_lists<'a>(
    effects: &[&'a dyn Effect],
    setups: &'a [Setup<'a>],
) -> Vec<Option<Vec<&'a dyn Effect>>> {
    setups
        .iter()
        .map(|s| {
            s.untestable.is_none().then(|| {
                let mut v: Vec<&dyn Effect> = effects.to_vec();
                v.push(s.scored());
                v
            })
        })
        .collect()
}

/// A candidate that could not be tested.
fn untested(s: &Setup) -> Candidate {
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
    }
}

/// A candidate scored by its signature's test (p-values not yet adjusted).
fn scored(s: &Setup, sig: &Signature, alpha: f64) -> Candidate {
    let t = sig.test();
    let ln_p_value = if t.dof > 0 {
        chi2_ln_sf(t.statistic, t.dof as f64)
    } else {
        0.0
    };
    let p_value = ln_p_value.exp();
    let lambda = noncentrality_for_power(t.dof.max(1) as f64, alpha, DETECTION_POWER);
    let params = s
        .scored()
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
    }
}

/// The candidates scored and ranked: testable ones by log p-value (ties: fewer degrees of
/// freedom first), untestable ones last; p-values Holm-adjusted. Each keeps its signature.
pub(crate) fn rank<'s>(
    setups: &[Setup],
    sigs: &'s [Option<Signature>],
    alpha: f64,
) -> Vec<(Candidate, Option<&'s Signature>)> {
    let mut ranking: Vec<(Candidate, Option<&Signature>)> = setups
        .iter()
        .zip(sigs)
        .map(|(s, sig)| match sig {
            None => (untested(s), None),
            Some(sig) => (scored(s, sig, alpha), Some(sig)),
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
    let tested = sigs.iter().filter(|s| s.is_some()).count().max(1);
    holm(ranking.iter_mut().map(|(c, _)| c), tested);
    ranking
}

/// Holm's step-down adjustment over the tested candidates (in rank order), in logs: no
/// underflow.
fn holm<'c>(ranked: impl Iterator<Item = &'c mut Candidate>, tested: usize) {
    let mut running = f64::NEG_INFINITY;
    for (rank, c) in ranked.filter(|c| c.untestable.is_none()).enumerate() {
        running = running.max((((tested - rank) as f64).ln() + c.ln_p_value).min(0.0));
        c.ln_p_adjusted = running;
        c.p_adjusted = running.exp();
    }
}

/// Pairs among the [`CONFOUNDING_LEADERS`] leading candidates whose signatures are nearly the
/// same on this run (canonical correlation above [`CONFOUNDING_CORRELATION`]), when one of the
/// two is significant at `alpha`.
pub(crate) fn confounding(
    ranking: &[(Candidate, Option<&Signature>)],
    alpha: f64,
) -> Vec<Confounding> {
    let mut out = vec![];
    let leaders: Vec<(&Candidate, &Signature)> = ranking
        .iter()
        .take(CONFOUNDING_LEADERS)
        .filter_map(|(c, s)| s.map(|s| (c, s)))
        .collect();
    // Each footprint once, and only for a pair with a significant member (an SVD of the 3N × q
    // whitened signature each: 68 ms of a consistent rung on a 60-h run, for no pair reported).
    let footprints: Vec<std::cell::OnceCell<nalgebra::DMatrix<f64>>> =
        leaders.iter().map(|_| std::cell::OnceCell::new()).collect();
    let of = |i: usize| footprints[i].get_or_init(|| footprint(leaders[i].1));
    for (ai, &(a, _)) in leaders.iter().enumerate() {
        for (bi, &(b, _)) in leaders.iter().enumerate().skip(ai + 1) {
            let significant = a.p_adjusted < alpha || b.p_adjusted < alpha;
            if !significant {
                continue;
            }
            let cc = canonical_correlation(of(ai), of(bi));
            if cc > CONFOUNDING_CORRELATION {
                // On the −2 ln p scale, fair between effects of different dof (raw statistics
                // are not: a 15-dof statistic 20 above a 3-dof one can be the weaker evidence).
                let gap = 2.0 * (b.ln_p_value - a.ln_p_value);
                out.push(Confounding {
                    a: a.effect.clone(),
                    b: b.effect.clone(),
                    canonical_correlation: cc,
                    statistic_gap: gap,
                    separated: gap.abs() >= SEPARATION_GAP,
                    separate_by: separate_by(&a.effect, &b.effect),
                });
            }
        }
    }
    out
}

/// What experiment would separate effects `a` and `b`.
pub(crate) fn separate_by(a: &str, b: &str) -> String {
    let accel = |e: &str| e.starts_with("acc-");
    let thermal = |e: &str| matches!(e, "temp-drift" | "acc-temp");
    let slow = |e: &str| matches!(e, "g2" | "drift-trend" | "drift-markov");
    if thermal(a) || thermal(b) {
        "a temperature excursion that is not synchronised with the gravity cone (e.g. a heater step mid-run)".into()
    } else if accel(a) && accel(b) {
        "another initial platform orientation or a second run at another latitude: bias, scale factor and misalignment project differently onto the gravity cone".into()
    } else if slow(a) && slow(b) {
        "a longer run: a trend keeps growing while g²-sensitive drift repeats with the sidereal day; another initial orientation also changes the g² signature".into()
    } else {
        "a longer run, or another latitude or initial platform orientation".into()
    }
}

/// Smallest noncentrality λ of χ²(k, λ) that exceeds the level-`alpha` critical value with
/// probability `power`, by bisection.
///
/// statrs has no noncentral χ², so its tail is Patnaik's two-moment approximation: χ²(k, λ) ≈
/// c·χ²(h) with h = (k+λ)²/(k+2λ), c = (k+2λ)/(k+λ) (same mean and variance), whose tail is
/// statrs' exact central one. The result is a planning figure (the detection limit quoted with
/// each estimate), where Patnaik's few-percent error in λ does not matter.
pub(crate) fn noncentrality_for_power(k: f64, alpha: f64, power: f64) -> f64 {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn c(effect: &str, ln_p: f64) -> Candidate {
        Candidate {
            effect: effect.into(),
            about: String::new(),
            statistic: 0.0,
            dof: 3.0,
            p_value: ln_p.exp(),
            p_adjusted: ln_p.exp(),
            ln_p_value: ln_p,
            ln_p_adjusted: ln_p,
            params: vec![],
            refit: None,
            untestable: None,
        }
    }

    #[test]
    fn holm_adjusts_in_logs_and_stays_monotone() {
        // p = 0.01, 0.03, 0.04 in rank order, 3 tested: 3·0.01 = 0.03, max(0.03, 2·0.03) = 0.06,
        // max(0.06, 1·0.04) = 0.06 (statsmodels.stats.multitest.multipletests, method="holm").
        let mut v = [
            c("a", 0.01f64.ln()),
            c("b", 0.03f64.ln()),
            c("d", 0.04f64.ln()),
        ];
        holm(v.iter_mut(), 3);
        let got: Vec<f64> = v.iter().map(|c| c.p_adjusted).collect();
        for (g, w) in got.iter().zip([0.03, 0.06, 0.06]) {
            assert!((g - w).abs() < 1e-12, "{got:?}");
        }
        // Underflowing p-values keep their logs.
        let mut v = [c("a", -5000.0), c("b", -4000.0)];
        holm(v.iter_mut(), 2);
        assert!((v[0].ln_p_adjusted - (-5000.0 + 2f64.ln())).abs() < 1e-9);
        assert_eq!(v[1].ln_p_adjusted, -4000.0);
        assert_eq!(v[1].p_adjusted, 0.0);
    }

    #[test]
    fn noncentrality_for_ninety_percent_power() {
        // k = 1 and 3, α = 0.01, power 0.9. Patnaik's approximation solved with scipy
        // (chi2.sf, brentq): 14.30315540504708 and 18.80766840985692; the exact noncentral
        // values (scipy.stats.ncx2): 14.87938716650248 and 19.247424136071395, 4 % and 2 % away.
        let l1 = noncentrality_for_power(1.0, 0.01, 0.9);
        assert!((l1 - 14.303_155_405_047_08).abs() < 1e-6, "{l1}");
        assert!((l1 / 14.879_387_166_502_48 - 1.0).abs() < 0.05);
        let l3 = noncentrality_for_power(3.0, 0.01, 0.9);
        assert!((l3 - 18.807_668_409_856_92).abs() < 1e-6, "{l3}");
        assert!((l3 / 19.247_424_136_071_395 - 1.0).abs() < 0.05);
    }
}
