//! Honest uncertainty: the 1σ a user reads carries what the run cannot rule out.
//!
//! Recordings from the independent truth simulator with set-up errors the recording states as
//! exact (start tilt and azimuth, clock rate, latitude, gravity, a daily tilt of the apparent
//! vertical), and with effects that compete with the set-up. Each run goes through the one path
//! every command takes: prepare → identify → `assess` (set-up settled, alternatives weighed).
//! Tolerances, and why:
//! - calibration with set-up errors drawn from the priors: RMS of error / total 1σ ≤ 1.2 and
//!   ≥ 99 % of errors within 3 total σ (the criteria; a calibrated 1σ gives 1.0 and
//!   99.7 %); the noise-only 1σ on the same runs must miss (RMS > 2), or the test shows nothing;
//! - trust: ≥ 90 % of those runs trusted (exit 0) — the set-up errors lie within their priors,
//!   so a distrust is a false alarm, and the budget over the contradiction test and the
//!   alternatives is a few percent at most.

use estimator_core::Sample;
use host_tool::assess::{assess, Assessment};
use host_tool::catalog;
use host_tool::identify::{build_model, identify, prepare, Config};
use host_tool::simulate::{simulate, Scenario, SetupErrors};

/// Simulates `sc`, prepares it with the recording's metadata (not the truth) and assesses the
/// paper model's fit. Returns the assessment and the true coefficients.
fn run(sc: &Scenario) -> (Assessment, [f64; 12]) {
    let sim = simulate(sc);
    let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
    let site = estimator_core::Site::new(sim.meta.latitude_deg.unwrap(), sim.meta.gravity_mps2);
    let cfg = Config::default();
    let prep = prepare(site, &samples, &cfg).unwrap();
    let effects = [catalog::paper()];
    let model = build_model(prep.site, &effects, &cfg).unwrap();
    let id = identify(&model, &prep, &cfg).unwrap();
    (
        assess(&effects, prep, &cfg, id).unwrap(),
        sim.truth.coefficient_array(),
    )
}

fn scenario(seed: u64, hours: f64, rate_s: f64) -> Scenario {
    let mut sc = Scenario::paper();
    sc.seed = seed;
    sc.hours = hours;
    sc.rate_s = rate_s;
    sc
}

/// Errors over total and over noise-only 1σ of the 12 drift coefficients.
fn z_scores(a: &Assessment, truth: &[f64; 12]) -> Vec<(f64, f64)> {
    let best = a.id.best();
    (0..12)
        .map(|k| {
            let e = best.value[k] - truth[k];
            (e / a.unc.total_sigma[k], e / a.unc.noise_sigma[k])
        })
        .collect()
}

#[test]
fn the_total_sigma_covers_set_up_errors_drawn_from_the_priors() {
    let priors = Config::default().setup;
    let seeds: Vec<u64> = (200..250).collect();
    let results: Vec<(Vec<(f64, f64)>, bool)> = std::thread::scope(|s| {
        let handles: Vec<_> = seeds
            .chunks(25)
            .map(|chunk| {
                s.spawn(move || {
                    chunk
                        .iter()
                        .map(|&seed| {
                            let mut sc = scenario(seed, 36.0, 10.0);
                            let half = priors.latitude_sigma(sc.latitude_deg) * 3f64.sqrt();
                            sc.setup_errors = SetupErrors::draw(&priors, half, seed);
                            let (a, truth) = run(&sc);
                            (z_scores(&a, &truth), a.reasons.is_empty())
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    let z: Vec<(f64, f64)> = results.iter().flat_map(|r| r.0.clone()).collect();
    let rms = |f: &dyn Fn(&(f64, f64)) -> f64| {
        (z.iter().map(|x| f(x).powi(2)).sum::<f64>() / z.len() as f64).sqrt()
    };
    let (total, noise) = (rms(&|x| x.0), rms(&|x| x.1));
    let within3 = z.iter().filter(|x| x.0.abs() < 3.0).count() as f64 / z.len() as f64;
    let trusted = results.iter().filter(|r| r.1).count();
    println!(
        "{} runs: RMS error/total 1σ {total:.2}, within 3σ {:.1} %, RMS error/noise-only 1σ {noise:.2}, trusted {trusted}",
        results.len(),
        100.0 * within3
    );
    assert!(total <= 1.2, "RMS error / total 1σ = {total:.2}");
    assert!(within3 >= 0.99, "within 3 total σ: {:.3}", within3);
    assert!(
        noise > 2.0,
        "the noise-only 1σ should miss the set-up: RMS {noise:.2}"
    );
    assert!(
        trusted * 10 >= results.len() * 9,
        "trusted {trusted} of {}",
        results.len()
    );
}

#[test]
fn a_drift_trend_is_not_blamed_on_the_latitude() {
    // The trap of the issue: trends of 1e-5 deg/h per h, 60 h at 1 s. The trend must be named
    // (not trusted, reason naming drift-trend) and the latitude never advised.
    for seed in [1, 2] {
        let mut sc = scenario(seed, 60.0, 1.0);
        sc.effects
            .push("drift-trend=1e-5,-1e-5,1e-5".parse().unwrap());
        let (a, _) = run(&sc);
        assert!(
            a.reasons.iter().any(|r| r.contains("drift-trend")),
            "seed {seed}: {:?}",
            a.reasons
        );
        assert!(
            !a.prep.findings.iter().any(|f| f.kind == "latitude"),
            "seed {seed}: the latitude was blamed"
        );
    }
}

#[test]
fn a_latitude_within_its_prior_is_estimated_and_one_beyond_it_is_named() {
    // 0.05° off a latitude written "39.1" (prior 1σ 0.029°): estimated from the data, named as a
    // repaired set-up finding, the coefficients within 3 total σ of the truth.
    let mut sc = scenario(7, 60.0, 10.0);
    sc.setup_errors.latitude_deg = 0.05;
    let (a, truth) = run(&sc);
    assert!(a.reasons.is_empty(), "{:?}", a.reasons);
    assert!(
        a.prep
            .findings
            .iter()
            .any(|f| f.kind == "set-up" && f.message.contains("latitude")),
        "{:?}",
        a.prep.findings
    );
    let worst = z_scores(&a, &truth)
        .iter()
        .map(|z| z.0.abs())
        .fold(0.0, f64::max);
    assert!(worst < 3.0, "worst error {worst:.2} total σ");
    // 0.5° off: beyond what "39.1" allows; not trusted, the reason names the latitude.
    sc.setup_errors.latitude_deg = 0.5;
    let (a, _) = run(&sc);
    assert!(
        a.reasons.iter().any(|r| r.contains("latitude")),
        "{:?}",
        a.reasons
    );
}
