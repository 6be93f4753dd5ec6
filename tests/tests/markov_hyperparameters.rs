//! `drift-markov`'s σ and τ from the data (issue 27, item 4): on Gauss–Markov recordings the
//! marginal-likelihood fit (`host_tool::identify::markov`) recovers the injected σ and τ, and the
//! model refitted there leaves white innovations; on a clean recording it does not invent a wander.
//!
//! Every run is the paper scenario from the independent truth simulator, 60 h at 10-s samples (the
//! simulator scales the raw noise so each 60-s mean keeps the paper's 1e-5 g), with one shared σ
//! and τ injected on the three axes (the model fits one shared pair: `identify::markov`'s docs).
//!
//! Tolerances:
//! - per seed, σ and τ within 3σ of the injected values, in ln units, σ being the half-width of
//!   the profile-likelihood 1σ interval on the truth's side (the likelihood's ridge bends, so the
//!   curvature's 1σ is too narrow on the long side: a seed 2σ off by its profile was 4–8σ off by
//!   the curvature): the truth is the ensemble's, one 60-h run holds only 5–30 correlation times,
//!   so the realisation's own σ and τ scatter about it by about the printed 1σ; 3σ is exceeded
//!   with probability 0.27 % per parameter for a correct 1σ;
//! - over the seeds, the mean of those z-scores within ±2: a mean of 3 independent z has 1σ 0.58,
//!   so this catches a bias of about 1σ per run (the 8-seed sweeps in docs/model.md gave |mean z| ≤ 0.52);
//! - white: Ljung–Box p ≥ 1e-3, the one definition's level (`consistency::Thresholds`), so a
//!   correct model fails by chance once in a thousand runs;
//! - clean run: σ below 1e-3 deg/h, a third of the smallest wander recovered here (0.003 deg/h,
//!   which gains ~200 in −2 ln L over the catalog's values, far above chance).

use estimator_core::{Sample, Site};
use host_tool::catalog::Catalog;
use host_tool::diagnose::{whiteness, DiagnoseConfig};
use host_tool::identify::markov::{tune, MarkovFit};
use host_tool::identify::{build_model, identify, prepare, Identification};
use host_tool::simulate::{simulate, InjectedEffect, Scenario};

/// Ljung–Box p of a fit's whitened innovations, at the diagnosis' lags.
fn whiteness_p(id: &Identification) -> f64 {
    let w: Vec<[f64; 3]> = id.innovations.iter().map(|r| r.whitened).collect();
    whiteness(&w, DiagnoseConfig::default().lags).p_value
}

/// Simulates seed `seed` with `effect` injected (none: clean), identifies the paper's model plus
/// `drift-markov` with the catalog's σ and τ, then tunes them. Returns the catalog fit's Ljung–Box
/// p, the tuned fit and its identification.
fn fit_markov(seed: u64, effect: Option<&str>) -> (f64, MarkovFit, Identification) {
    let mut sc = Scenario::paper();
    sc.seed = seed;
    sc.rate_s = 10.0;
    if let Some(e) = effect {
        let injected: InjectedEffect = e.parse().unwrap();
        sc.effects.push(injected);
    }
    let sim = simulate(&sc);
    let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
    let cfg = DiagnoseConfig::default().identify;
    let prep = prepare(Site::new(sc.latitude_deg, sc.gravity_mps2), &samples, &cfg).unwrap();
    let effects = Catalog::builtin()
        .model_effects(&["drift-markov".to_string()])
        .unwrap();
    let model = build_model(prep.site, &effects, &cfg).unwrap();
    let id = identify(&model, &prep, &cfg).unwrap();
    let before = whiteness_p(&id);
    let (_, tuned) = tune(Catalog::builtin(), &prep, &effects, &cfg, id).unwrap();
    let gm = tuned.markov.expect("drift-markov is in the model: tuned");
    eprintln!(
        "seed {seed} {effect:?}: catalog σ, τ Ljung–Box p {before:.2e}; {}; after p {:.2e}",
        gm.line(),
        whiteness_p(&tuned)
    );
    (before, gm, tuned)
}

/// z-score in ln units of an estimate against the truth: the distance over the half-width of the
/// profile-likelihood 1σ interval on the truth's side.
fn z_ln(est: f64, [lo, hi]: [f64; 2], truth: f64) -> f64 {
    let d = (est / truth).ln();
    let half = if truth < est { est / lo } else { hi / est };
    d / half.ln()
}

fn recovers(sigma: f64, tau: f64, seeds: [u64; 3]) {
    let effect = format!("drift-markov={sigma},{sigma},{sigma}:{tau},{tau},{tau}");
    let mut zs = vec![];
    for seed in seeds {
        let (_, gm, id) = fit_markov(seed, Some(&effect));
        assert!(!gm.at_bound, "seed {seed}: {}", gm.line());
        let zs_ = z_ln(gm.sigma_degph, gm.sigma_interval_degph, sigma);
        let zt = z_ln(gm.tau_h, gm.tau_interval_h, tau);
        assert!(
            zs_.abs() <= 3.0 && zt.abs() <= 3.0,
            "seed {seed}: z σ {zs_:.2}, z τ {zt:.2}: {}",
            gm.line()
        );
        let p = whiteness_p(&id);
        assert!(
            p >= 1e-3,
            "seed {seed}: tuned fit not white, Ljung–Box p {p:.2e}"
        );
        zs.push((zs_, zt));
    }
    let n = zs.len() as f64;
    let mean = (
        zs.iter().map(|z| z.0).sum::<f64>() / n,
        zs.iter().map(|z| z.1).sum::<f64>() / n,
    );
    eprintln!(
        "σ {sigma} τ {tau}: mean z (σ, τ) = ({:.2}, {:.2})",
        mean.0, mean.1
    );
    assert!(
        mean.0.abs() <= 2.0 && mean.1.abs() <= 2.0,
        "biased: mean z {mean:?}"
    );
}

#[test]
fn a_short_small_wander_is_recovered_and_whitened() {
    recovers(0.003, 2.0, [21, 22, 23]);
}

#[test]
fn a_long_large_wander_is_recovered_and_whitened() {
    recovers(0.02, 12.0, [31, 32, 33]);
}

#[test]
fn a_clean_run_gets_no_invented_wander() {
    let (_, gm, _) = fit_markov(41, None);
    assert!(gm.sigma_degph < 1e-3, "{}", gm.line());
}
