//! The plan's predicted total 1σ (issue 26): a designed run's noise bound plus its set-up's
//! share ([`host_tool::plan::design_setup_cov`], the same priors and code `identify` uses), held
//! against the total 1σ `identify` reports on simulated runs of that design.

use estimator_core::{Sample, Site};
use host_tool::assess::assess;
use host_tool::catalog;
use host_tool::identify::{build_model, identify, prepare_oriented, Config};
use host_tool::plan::{design_cov, design_setup_cov, Design};
use host_tool::simulate::{simulate, Scenario};

/// A level 24-h run at 10 s (the sweep's scenario): at the default priors the latitude, written
/// as 39.1 (1σ 0.029°), dominates DXx's total 1σ by two orders of magnitude.
fn design() -> Design {
    let sc = Scenario::paper();
    let rate_s = 10.0;
    Design {
        orientation_deg: [0.0; 3],
        hours: 24.0,
        rate_s,
        // The simulator's raw noise: its `accel_sigma_mps2` is the 1σ of a 60-s mean.
        raw_sigma_mps2: [sc.accel_sigma_mps2 * (60.0 / rate_s).sqrt(); 3],
    }
}

/// The total 1σ `identify` reports on a simulated run of `d` with `seed` (its assessed fit, as
/// the CLI prints it), less the model-averaging spread: the spread between explanations a single
/// run cannot tell apart is the run's own (a joint fit, what a plan predicts, carries none).
fn reported_total(d: &Design, seed: u64, cfg: &Config) -> Vec<f64> {
    let mut sc = Scenario::paper();
    sc.seed = seed;
    sc.hours = d.hours;
    sc.rate_s = d.rate_s;
    sc.initial_orientation_deg = d.orientation_deg;
    let sim = simulate(&sc);
    let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
    let site = Site::new(sc.latitude_deg, None);
    let theta0 = d.orientation_deg.map(f64::to_radians);
    let prep = prepare_oriented(site, &samples, cfg, theta0).unwrap();
    let effects = [catalog::paper()];
    let model = build_model(prep.site, &effects, cfg).unwrap();
    let id = identify(&model, &prep, cfg).unwrap();
    let unc = assess(catalog::Catalog::builtin(), &effects, prep, cfg, id)
        .unwrap()
        .unc;
    (0..unc.total_sigma.len())
        .map(|k| {
            let spread = unc.model_spread.get(k).copied().unwrap_or(0.0);
            (unc.total_sigma[k].powi(2) - spread * spread)
                .max(0.0)
                .sqrt()
        })
        .collect()
}

#[test]
fn the_predicted_total_sigma_is_what_identify_reports_on_the_designed_run() {
    // Tolerances, and why:
    // - per coefficient, the median over 9 seeds of reported/predicted total 1σ within 20 %:
    //   both come from the same code and priors, but `identify` works on noisy data: the noise
    //   floor is estimated (±1 %), the data shrink a knob (latitude, gravity) by what they say
    //   about it, and the daily drift's size grows where its evidence is higher — up to 2.5× on
    //   single seeds (DZx, DYx), the median by ≤ 2 % (16 joint seeds of the CLI sweep); measured
    //   here: medians 0.999–1.001;
    // - DXx's predicted total at least 10× its noise-only 1σ: the latitude's share alone is
    //   ~200× on this design (identify's own table), so a plan without the set-up fails it.
    let cfg = Config::default();
    let effects = [catalog::paper()];
    let d = design();
    let site = Site::new(39.1, None);
    let params = Scenario::paper().coefficients;
    let bound = design_cov(site, &effects, &d, &params, &cfg).unwrap();
    let setup = design_setup_cov(site, &effects, &d, &params, &cfg).unwrap();
    let noise: Vec<f64> = (0..12).map(|k| bound[(k, k)].sqrt()).collect();
    let total: Vec<f64> = (0..12)
        .map(|k| (bound[(k, k)] + setup[(k, k)]).sqrt())
        .collect();
    let seeds: Vec<u64> = (700..709).collect();
    let cfg = &cfg;
    let reported: Vec<Vec<f64>> = std::thread::scope(|s| {
        let handles: Vec<_> = seeds
            .iter()
            .map(|&seed| s.spawn(move || reported_total(&d, seed, cfg)))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for k in 0..12 {
        let mut r: Vec<f64> = reported.iter().map(|t| t[k] / total[k]).collect();
        r.sort_by(f64::total_cmp);
        let median = r[r.len() / 2];
        eprintln!(
            "coef {k}: predicted total {:.3e} (noise only {:.3e}), reported/predicted median {median:.3} [{:.2}, {:.2}]",
            total[k],
            noise[k],
            r[0],
            r[r.len() - 1]
        );
        assert!(
            (median - 1.0).abs() < 0.2,
            "coefficient {k}: median reported/predicted total 1σ {median:.3}"
        );
    }
    // DXx (index 1): the latitude's share.
    assert!(
        total[1] > 10.0 * noise[1],
        "DXx: predicted total {:.3e}, noise only {:.3e}",
        total[1],
        noise[1]
    );
}
