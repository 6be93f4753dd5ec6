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
use host_tool::catalog::{self, Catalog};
use host_tool::identify::{build_model, identify, prepare, Config};
use host_tool::simulate::{simulate, Scenario, SetupErrors};

/// Simulates `sc`, prepares it with the recording's metadata (not the truth) and assesses the
/// paper model's fit with the default priors (the tool's assumptions). Returns the assessment
/// and the true coefficients.
fn run(sc: &Scenario) -> (Assessment, [f64; 12]) {
    run_with(sc, Config::default())
}

/// The settings of a user who states the set-up's priors (`--latitude-sigma-deg`,
/// `--clock-sigma-ppm`, `--gravity-sigma-ppm`) at the defaults' values: no longer assumptions.
fn stated_priors() -> Config {
    let mut cfg = Config::default();
    cfg.setup.assumed = [false; 3];
    cfg
}

/// [`run`] with the settings `cfg`.
fn run_with(sc: &Scenario, cfg: Config) -> (Assessment, [f64; 12]) {
    let sim = simulate(sc);
    let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
    let site = estimator_core::Site::new(sim.meta.latitude_deg.unwrap(), sim.meta.gravity_mps2);
    let prep = prepare(site, &samples, &cfg).unwrap();
    let effects = [catalog::paper()];
    let model = build_model(prep.site, &effects, &cfg).unwrap();
    let id = identify(&model, &prep, &cfg).unwrap();
    (
        assess(Catalog::builtin(), &effects, prep, &cfg, id).unwrap(),
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

/// Runs of 36 h at 10 s with every set-up error drawn from the priors by its seed (`adjust`
/// then changes the draw), assessed with the priors stated by the user (at the defaults'
/// values: with the defaults a latitude moved within its digits is also a clock running fast,
/// `a_clock_running_fast_is_not_trusted_as_a_latitude_move`), `per_thread` seeds to a thread:
/// each run's z-scores and whether it is trusted.
fn drawn_runs(
    seeds: &[u64],
    per_thread: usize,
    adjust: impl Fn(&mut Scenario) + Sync,
) -> Vec<(Vec<(f64, f64)>, bool)> {
    drawn(
        seeds,
        per_thread,
        (36.0, 10.0),
        stated_priors,
        adjust,
        |a, _, truth| (z_scores(a, truth), a.reasons.is_empty()),
    )
}

/// Runs of `hours` at `rate_s` with every set-up error drawn from the priors by its seed
/// (`adjust` then changes the draw), assessed with the settings `cfg` gives, `per_thread` seeds
/// to a thread: what `measure` takes of each assessment (with its scenario and the truth).
fn drawn<T: Send>(
    seeds: &[u64],
    per_thread: usize,
    (hours, rate_s): (f64, f64),
    cfg: fn() -> Config,
    adjust: impl Fn(&mut Scenario) + Sync,
    measure: impl Fn(&Assessment, &Scenario, &[f64; 12]) -> T + Sync,
) -> Vec<T> {
    let priors = Config::default().setup;
    let (adjust, measure) = (&adjust, &measure);
    std::thread::scope(|s| {
        let handles: Vec<_> = seeds
            .chunks(per_thread)
            .map(|chunk| {
                s.spawn(move || {
                    chunk
                        .iter()
                        .map(|&seed| {
                            let mut sc = scenario(seed, hours, rate_s);
                            let half = priors.latitude_sigma(sc.latitude_deg) * 3f64.sqrt();
                            sc.setup_errors = SetupErrors::draw(&priors, half, seed);
                            adjust(&mut sc);
                            let (a, truth) = run_with(&sc, cfg());
                            measure(&a, &sc, &truth)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    })
}

#[test]
fn the_total_sigma_covers_set_up_errors_drawn_from_the_priors() {
    let seeds: Vec<u64> = (200..250).collect();
    let results = drawn_runs(&seeds, 25, |sc| {
        // A trend drawn at its prior is above a 36-h run's detection limit most often: the
        // alternatives' to name, not the 1σ's to cover
        // (`trends_drawn_from_their_prior_are_named_or_covered`).
        sc.setup_errors.drift_trend_deg_h_per_h = [0.0; 3];
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
fn trends_drawn_from_their_prior_are_named_or_covered() {
    // Every set-up error drawn from its prior, the drift trend's too (0.0003 deg/h a day per
    // axis): at 36 h such a trend is mostly above the detection limit, and the run is then not
    // trusted (its reasons name it). A trusted run must be calibrated: no coefficient beyond 3
    // total σ (the worst of 14 trusted in 40 swept was 2.54σ; before the trend's path through the
    // latitude was carried, 80 of 480 coefficients lay beyond 3σ), RMS ≤ 1.2 as for the other
    // set-up errors — over at least 5 trusted runs, or the test shows nothing.
    let seeds: Vec<u64> = (300..316).collect();
    let results = drawn_runs(&seeds, 8, |_| {});
    let trusted: Vec<f64> = results
        .iter()
        .filter(|r| r.1)
        .flat_map(|r| r.0.iter().map(|z| z.0))
        .collect();
    let rms = (trusted.iter().map(|z| z * z).sum::<f64>() / trusted.len().max(1) as f64).sqrt();
    let worst = trusted.iter().fold(0.0f64, |m, z| m.max(z.abs()));
    println!(
        "{} runs, {} trusted: RMS error/total 1σ {rms:.2}, worst {worst:.2}",
        results.len(),
        trusted.len() / 12
    );
    assert!(trusted.len() >= 5 * 12, "{} trusted", trusted.len() / 12);
    assert!(worst <= 3.0, "a trusted coefficient {worst:.2} total σ off");
    assert!(rms <= 1.2, "RMS error / total 1σ of trusted runs {rms:.2}");
}

#[test]
fn the_latitude_is_estimated_with_a_1sigma_that_covers_the_truth() {
    // The set-up drawn from its priors, the drift trend's too, 48 h at 30 s: a trend bends the
    // latitude's signature. With its posterior 1σ (the slow drifts held at zero, ~0.003°) the
    // latitude the data give missed the truth by 7–18σ on 16 of 40 such runs, and 7 were
    // distrusted for a latitude "outside its digits" that lay within them (the default priors,
    // as here); with the 1σ the run supports (`knob_sigma`: the slow drifts free, ~0.02°) the
    // RMS was 1.35 and the worst 2.56.
    // Tolerances: RMS ≤ 1.6 and none beyond 3.5 over 16 runs (a calibrated 1σ exceeds 3.5 once
    // in 2 000 runs); the posterior alone must miss (RMS > 3), or the test shows nothing.
    let seeds: Vec<u64> = (400..416).collect();
    let runs = drawn(
        &seeds,
        8,
        (48.0, 30.0),
        Config::default,
        |_| {},
        |a, sc, _| {
            let lat = a
                .unc
                .contributions
                .iter()
                .find(|c| c.source == "latitude")
                .expect("the latitude's contribution");
            // The estimate's offset from the stated latitude against the truth's (the metadata
            // minus the truth is the set-up error).
            let err = lat.offset.expect("estimated") + sc.setup_errors.latitude_deg;
            (
                err / lat.knob_sigma(),
                err / lat.posterior_sigma,
                a.reasons.clone(),
            )
        },
    );
    let rms = |z: &[f64]| (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
    let with_drifts = rms(&runs.iter().map(|r| r.0).collect::<Vec<_>>());
    let posterior = rms(&runs.iter().map(|r| r.1).collect::<Vec<_>>());
    let worst = runs.iter().fold(0.0f64, |m, r| m.max(r.0.abs()));
    println!("latitude error / its 1σ: RMS {with_drifts:.2} (worst {worst:.2}); / the posterior alone: RMS {posterior:.2}");
    assert!(with_drifts <= 1.6, "RMS {with_drifts:.2}");
    assert!(worst <= 3.5, "a latitude {worst:.2}σ off");
    assert!(
        posterior > 3.0,
        "the posterior alone should miss: RMS {posterior:.2}"
    );
    for r in &runs {
        assert!(
            !r.2.iter().any(|m| m.contains("outside what the stated")),
            "the truth lies within the digits: {:?}",
            r.2
        );
    }
}

#[test]
fn a_trend_below_its_detection_limit_moves_no_coefficient_through_the_latitude() {
    // A trend on x at half its detection limit (60 h at 1 s, 2e-6 deg/h per h) bends the
    // latitude's signature: it moved the latitude by 1.7 of its 1σ and DXx with it by 1.61 total
    // σ, while each term taken with the other held (the trend's set-up term, the sensitivity
    // table) showed 0.03σ. With the knobs marginalised with the slow drifts free it moves no
    // coefficient by more than 0.4σ; beyond 1σ, the limit for an unflagged move, fails.
    let clean = scenario(3, 60.0, 1.0);
    let mut with = clean.clone();
    with.effects
        .push("drift-trend=-1.98249e-06,0,0".parse().unwrap());
    let (a_with, a_clean) = std::thread::scope(|s| {
        let h = s.spawn(|| run(&clean).0);
        (run(&with).0, h.join().unwrap())
    });
    for k in 0..12 {
        let moved =
            (a_with.id.best().value[k] - a_clean.id.best().value[k]) / a_with.unc.total_sigma[k];
        assert!(
            moved.abs() <= 1.0,
            "{} moved by {moved:+.2} total σ",
            a_with.id.params[k].name
        );
    }
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
            !a.prep.findings.iter().any(|f| f.kind.name() == "latitude"),
            "seed {seed}: the latitude was blamed"
        );
    }
}

#[test]
fn a_latitude_within_its_prior_is_estimated_and_one_beyond_it_is_named() {
    // 0.05° off a latitude written "39.1" (prior 1σ 0.029°): estimated from the data, named as a
    // repaired set-up finding, the coefficients within 3 total σ of the truth.
    // With the priors stated by the user (at the defaults' values): with the defaults' assumed
    // clock the same data are also a clock 640 ppm fast, and the result is not trusted.
    let mut sc = scenario(7, 60.0, 10.0);
    sc.setup_errors.latitude_deg = 0.05;
    let (a, _) = run(&sc);
    assert!(
        a.reasons.iter().any(|r| r.contains("rests on the assumed")),
        "{:?}",
        a.reasons
    );
    let (a, truth) = run_with(&sc, stated_priors());
    assert!(a.reasons.is_empty(), "{:?}", a.reasons);
    assert!(
        a.prep
            .findings
            .iter()
            .any(|f| f.kind.name() == "set-up" && f.message.contains("latitude")),
        "{:?}",
        a.prep.findings
    );
    let worst = z_scores(&a, &truth)
        .iter()
        .map(|z| z.0.abs())
        .fold(0.0, f64::max);
    assert!(worst < 3.0, "worst error {worst:.2} total σ");
    // 0.5° off: beyond what "39.1" allows, a misstated latitude. It beats every other
    // explanation (a clock 7000 ppm off comes closest) and is repaired by name; the coefficients
    // are then the fit's at the data's latitude, within 3 total σ of the truth.
    sc.setup_errors.latitude_deg = 0.5;
    let (a, truth) = run_with(&sc, stated_priors());
    assert!(a.reasons.is_empty(), "{:?}", a.reasons);
    assert_repaired(&a, "latitude is misstated");
    assert_within_3_sigma(&a, &truth);
}

/// The finding that names a repaired set-up.
fn assert_repaired(a: &Assessment, what: &str) {
    assert!(
        a.prep
            .findings
            .iter()
            .any(|f| f.kind.name() == "set-up" && f.message.contains(what)),
        "no `{what}` among {:?}",
        a.prep.findings
    );
}

/// Every coefficient within 3 total σ of the truth (a calibrated 1σ misses that once in 370
/// coefficients; these runs check 12 each).
fn assert_within_3_sigma(a: &Assessment, truth: &[f64; 12]) {
    let worst = z_scores(a, truth)
        .iter()
        .map(|z| z.0.abs())
        .fold(0.0, f64::max);
    assert!(worst < 3.0, "worst error {worst:.2} total σ");
}

#[test]
fn a_misstated_gravity_is_repaired_and_a_misstated_clock_is_never_trusted_wrong() {
    // Gravity 900 ppm off (0.09 %: acc-scale was added, 29σ off): the data know gravity to
    // 0.2 ppm, the misstated gravity beats every explanation and is repaired by name. A recorder
    // clock 1000 ppm fast (50 times its prior; drift-trend or g2 were added, 6–64σ off): on 36 h
    // a latitude within its digits and a drift trend explain it almost as well, so the result
    // must either be repaired by name and right, or not trusted with the clock among the reasons.
    for seed in [3, 4] {
        let mut sc = scenario(seed, 36.0, 10.0);
        sc.setup_errors.gravity_ppm = 900.0;
        let (a, truth) = run(&sc);
        assert!(a.reasons.is_empty(), "seed {seed}: {:?}", a.reasons);
        assert_repaired(&a, "gravity is misstated");
        assert_within_3_sigma(&a, &truth);
        let mut sc = scenario(seed, 36.0, 10.0);
        sc.setup_errors.clock_ppm = 1000.0;
        let (a, truth) = run(&sc);
        if a.reasons.is_empty() {
            assert_repaired(&a, "clock rate is misstated");
            assert_within_3_sigma(&a, &truth);
        } else {
            assert!(
                a.reasons.iter().any(|r| r.contains("clock")),
                "seed {seed}: {:?}",
                a.reasons
            );
        }
    }
}

#[test]
fn a_clock_running_fast_is_not_trusted_as_a_latitude_move() {
    // A recorder clock 300 ppm fast (15 times its default prior) on a latitude written "39.1":
    // the data move the latitude 0.02° within its digits and fit; a clock 300 ppm fast fits
    // them as well (the two differ only in their priors), and the coefficients differ by 6σ of
    // the total 1σ the latitude's data left (DXx was 8σ off, trusted). Either the result rests
    // on the assumed clock prior — not trusted, the clock named — or the total 1σ carries the
    // difference and the trusted answer is within 3 of it (since the knobs are marginalised
    // with the slow drifts free, the latitude's share is wide enough on seed 2: worst 1.36σ).
    for seed in [1, 2] {
        let mut sc = scenario(seed, 60.0, 10.0);
        sc.setup_errors.clock_ppm = 300.0;
        let (a, truth) = run(&sc);
        if a.reasons.is_empty() {
            assert_within_3_sigma(&a, &truth);
        } else {
            assert!(
                a.reasons
                    .iter()
                    .any(|r| r.contains("misstated clock rate")
                        && r.contains("rests on the assumed")),
                "seed {seed}: {:?}",
                a.reasons
            );
        }
        // The same recording with a clock as stated (none of the above): trusted.
        let (a, truth) = run(&scenario(seed, 60.0, 10.0));
        assert!(a.reasons.is_empty(), "seed {seed}: {:?}", a.reasons);
        assert_within_3_sigma(&a, &truth);
    }
}

#[test]
fn a_drift_trend_is_not_repaired_as_a_misstated_clock() {
    // The reverse trap: a real trend (3 axes, ~5× its detection limit at 36 h) is close to a
    // clock error. The tool must not repair the clock (which would trust wrong coefficients):
    // not trusted, and no set-up finding.
    for seed in [1, 2] {
        let mut sc = scenario(seed, 36.0, 10.0);
        sc.effects
            .push("drift-trend=2e-5,-2e-5,1.5e-5".parse().unwrap());
        let (a, _) = run(&sc);
        assert!(!a.reasons.is_empty(), "seed {seed}: trusted");
        assert!(
            !a.prep
                .findings
                .iter()
                .any(|f| f.message.contains("misstated")),
            "seed {seed}: {:?}",
            a.prep.findings
        );
    }
}

#[test]
fn an_alternatives_shift_is_what_refitting_with_it_gives() {
    // The linearised shift of the coefficients under an absent effect (−Ψ_N β̂) against the
    // converged refit with the effect: on a run with a drift trend of 3e-5 deg/h per h, the two
    // agree within 15 % of the shift plus one total 1σ (the refit is nonlinear and converges to
    // 0.01σ; the linearisation is about the paper model's fit, which the trend bends).
    let mut sc = scenario(4, 60.0, 10.0);
    sc.effects
        .push("drift-trend=3e-5,-2e-5,3e-5".parse().unwrap());
    let sim = simulate(&sc);
    let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
    let site = estimator_core::Site::new(sim.meta.latitude_deg.unwrap(), sim.meta.gravity_mps2);
    let mut cfg = Config::default();
    // Without the slow drifts' marginalisation (daily, trend), which moves the assessed estimate
    // off the fit that both the linearisation and the refit below start from.
    cfg.setup.daily_drift_deg_h = 0.0;
    cfg.setup.drift_trend_deg_h_per_day = 0.0;
    let prep = prepare(site, &samples, &cfg).unwrap();
    let paper = [catalog::paper()];
    let id = identify(&build_model(prep.site, &paper, &cfg).unwrap(), &prep, &cfg).unwrap();
    let a = assess(Catalog::builtin(), &paper, prep.clone(), &cfg, id.clone()).unwrap();
    let alt = a
        .alternatives
        .iter()
        .find(|x| x.effect == "drift-trend" && !x.instead_of_setup)
        .expect("drift-trend weighed");
    assert!(alt.evidence_gain > 10.0, "gain {}", alt.evidence_gain);
    let with = [catalog::paper(), catalog::builtin("drift-trend").unwrap()];
    // About the assessed fit: the set-up where prior and data put it.
    let refit = identify(
        &build_model(a.prep.site, &with, &cfg).unwrap(),
        &a.prep,
        &cfg,
    )
    .unwrap();
    for k in 0..12 {
        let linear = alt.shift[k];
        let actual = refit.best().value[k] - a.id.best().value[k];
        let tol = 0.15 * linear.abs() + a.unc.total_sigma[k];
        assert!(
            (linear - actual).abs() < tol,
            "{}: linearised {linear:.3e}, refit {actual:.3e}",
            id.params[k].name
        );
    }
}

#[test]
fn a_daily_drift_is_carried_in_the_total_sigma_or_named() {
    // A gyro drift that follows the solar day hides in the coefficients on one run: the platform
    // turns with the sidereal day, so D_j·A(t) holds a sinusoid of nearly that period (a
    // 0.001 deg/h daily sine was trusted 4.8–6.8 total σ off). At 1e-3 deg/h per axis (3× the
    // thermal prior per component, any phase) every run must be either not trusted or within
    // 3.5 total σ on all 12 coefficients (for a calibrated 1σ the largest of 12 |z| exceeds 3.5
    // in 0.6 % of runs); at 3e-3 the data see it: not trusted, `drift-daily` named.
    let cases = [(1e-3, [31, 32, 33, 34]), (3e-3, [35, 36, 0, 0])];
    for (amplitude, seeds) in cases {
        for seed in seeds.into_iter().filter(|s| *s > 0) {
            let mut sc = scenario(seed, 60.0, 10.0);
            let phase = |i: u64| (seed * 7 + i * 3) as f64;
            sc.setup_errors.daily_drift_deg_h = [0, 1, 2]
                .map(phase)
                .map(|p| [p.cos(), p.sin()])
                .as_flattened()
                .try_into()
                .unwrap();
            for d in &mut sc.setup_errors.daily_drift_deg_h {
                *d *= amplitude;
            }
            let (a, truth) = run_with(&sc, stated_priors());
            let worst = z_scores(&a, &truth)
                .iter()
                .map(|z| z.0.abs())
                .fold(0.0, f64::max);
            println!(
                "daily drift {amplitude:e}, seed {seed}: worst {worst:.2} total σ, reasons {:?}",
                a.reasons
            );
            if amplitude > 2e-3 {
                assert!(
                    a.reasons.iter().any(|r| r.contains("drift-daily")),
                    "seed {seed}: {:?}",
                    a.reasons
                );
            } else {
                assert!(
                    !a.reasons.is_empty() || worst < 3.5,
                    "seed {seed}: trusted, worst error {worst:.2} total σ"
                );
            }
        }
    }
}

#[test]
fn a_drift_with_the_recorded_temperature_is_carried_not_trusted_wrong() {
    // Found by a sweep of random recordings: a drift of 0.003 deg/h per °C (24 h at 30 s, 60° N,
    // the temperature recorded), trusted with DX0 5.0 total σ off (the catalog's `temp-drift`,
    // at a prior of 0.1 deg/h/°C, was not plausible). Carried as a set-up drift it is trusted
    // within 2.7σ; trusted must mean within 3 total σ, as everywhere here.
    let mut sc = scenario(1020, 24.0, 30.0);
    sc.latitude_deg = 60.25;
    sc.write_temp = true;
    sc.effects
        .push("temp-drift=0.00284,0.00187,-0.00241".parse().unwrap());
    let (a, truth) = run(&sc);
    if a.reasons.is_empty() {
        assert_within_3_sigma(&a, &truth);
    }
    // Clean runs with a recorded temperature stay trusted: one day does not separate a
    // temperature drift from the coefficients, and with the catalog's effect plausible at its
    // prior but not carried, 6 of 40 such runs were distrusted: these six (the other 34 of a
    // sweep of 40 were trusted either way).
    let seeds = [12u64, 23, 24, 28, 32, 33];
    let runs: Vec<_> = std::thread::scope(|s| {
        let handles: Vec<_> = seeds
            .iter()
            .map(|&seed| {
                s.spawn(move || {
                    let mut sc = scenario(seed, 24.0, 10.0);
                    sc.write_temp = true;
                    run(&sc).0.reasons
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for (seed, reasons) in seeds.iter().zip(&runs) {
        assert!(reasons.is_empty(), "clean seed {seed}: {reasons:?}");
    }
}

#[test]
fn a_latitude_written_minus_30_3_keeps_its_prior() {
    // Found by a sweep of random recordings: −30.3 came back from radians as
    // −30.299999999999997, read as written to 15 decimals (a prior of 1e-4° for 0.029°); the
    // run, 0.032° off that latitude (60 h at 10 s, set-up errors drawn from the priors, seed
    // 1073), had its clock "repaired" to 285 ppm and was trusted 46.6 total σ off.
    let priors = Config::default().setup;
    let mut sc = scenario(1073, 60.0, 10.0);
    sc.latitude_deg = -30.3;
    let half = priors.latitude_sigma(sc.latitude_deg) * 3f64.sqrt();
    sc.setup_errors = SetupErrors::draw(&priors, half, sc.seed);
    let (a, truth) = run(&sc);
    let lat = a
        .unc
        .contributions
        .iter()
        .find(|c| c.source == "latitude")
        .unwrap();
    assert!(
        lat.prior.starts_with("0.029"),
        "latitude prior {}",
        lat.prior
    );
    if a.reasons.is_empty() {
        assert_within_3_sigma(&a, &truth);
    }
}

#[test]
fn a_drift_the_data_see_is_not_carried_as_a_set_up_drift() {
    // Found by a sweep of random recordings: a 12-h sine of 7e-4 deg/h (outside the catalog;
    // 24 h at 10 s, set-up errors from the priors, seed 1072) made the data size the daily drift
    // to 17× its prior; its catalog twin (gain 8.9, short of the 10 that settles it) was exempt
    // as carried, and four coefficients ended 3.0–3.8 total σ off, trusted. A drift the data see
    // is weighed like any alternative: not trusted, or within 3 total σ.
    let priors = Config::default().setup;
    let mut sc = scenario(1072, 24.0, 10.0);
    let half = priors.latitude_sigma(sc.latitude_deg) * 3f64.sqrt();
    sc.setup_errors = SetupErrors::draw(&priors, half, sc.seed);
    sc.effects.push(
        "drift-sine=0.000699,-0.000434,-0.000521:12"
            .parse()
            .unwrap(),
    );
    let (a, truth) = run(&sc);
    if a.reasons.is_empty() {
        assert_within_3_sigma(&a, &truth);
    }
}
