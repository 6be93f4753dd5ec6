//! The paper's scenario (Table 1 truth, 39.1° N, 60-s filter period, 60 h, 1-s samples, fixed
//! seed), simulated by the independent truth simulator and identified by the default pipeline.
//!
//! Acceptance: every coefficient within 3σ of the truth and within the paper's own 60-h error
//! (≤ 3.0 % relative, its worst entry in Table 2). The 3σ bound is the honest-uncertainty check:
//! with 12 coefficients a consistent 1σ puts all of them inside 3σ with probability ~97 %; the seed
//! is fixed, so the test is deterministic. The accuracy benchmark (`driftid bench accuracy`) is
//! the statistical check over many seeds.

use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::{Model, Propagation, Sample, Site, PAPER_EFFECTS};
use host_tool::identify::{identify, prepare, Config};
use host_tool::simulate::{simulate, Scenario};

fn run(seed: u64) -> (host_tool::identify::Identification, [f64; 12]) {
    let mut sc = Scenario::paper();
    sc.seed = seed;
    let sim = simulate(&sc);
    let samples: Vec<Sample> = sim
        .samples
        .iter()
        .map(|s| Sample {
            t_s: s.t_s,
            specific_force: s.specific_force_mps2,
            temp_c: f64::NAN,
        })
        .collect();
    let site = Site::new(sc.latitude_deg, sc.gravity_mps2);
    let model = Model::new(
        site,
        &PAPER_EFFECTS,
        arw_deg2ph_to_rad2ps(1e-8),
        Propagation::default(),
    )
    .unwrap();
    let cfg = Config::default();
    let prep = prepare(site, &samples, &cfg).unwrap();
    assert_eq!(
        prep.measurements.len(),
        3601,
        "60 h of 60-s windows from t = 0 to 216000 s inclusive"
    );
    (
        identify(&model, &prep, &cfg).unwrap(),
        sim.truth.coefficient_array(),
    )
}

#[test]
fn paper_scenario_converges_within_3_sigma_and_the_papers_errors() {
    let (id, truth) = run(7);
    let best = id.refined.as_ref().expect("default identification refines");
    assert!((id.final_time_h - 60.0).abs() < 0.01);
    for k in 0..12 {
        let (v, s, t) = (best.value[k], best.sigma(k), truth[k]);
        let name = id.params[k].name;
        assert!(
            (v - t).abs() <= 3.0 * s,
            "{name}: {v} vs truth {t}: {:.2} σ (σ = {s:e})",
            (v - t) / s
        );
        assert!(
            ((v - t) / t).abs() <= 0.03,
            "{name}: relative error {:.3} % > 3 %",
            100.0 * (v - t) / t
        );
    }
    // Consistency of the final innovations: mean NIS/3 of 3601 updates has a 1σ spread of
    // sqrt(2/(3·3601)) ≈ 0.014; ±0.1 is ~7σ, so only an inconsistent filter fails.
    let nis = id.nis_mean();
    assert!((nis - 1.0).abs() < 0.1, "mean NIS/3 = {nis}");
}

/// The paper's single pass (what the firmware runs) is far less accurate on the same data, and
/// claims more than it knows: the refinement must matter. Seed 1 is one of the seeds on which the
/// single pass fails by tens of percent (model.md: median ~6-7 %, up to 189 %).
#[test]
fn paper_single_pass_is_overconfident_where_the_refinement_is_not() {
    let (id, truth) = run(1);
    let worst_z = |value: &[f64], k_sigma: &dyn Fn(usize) -> f64| {
        (0..12)
            .map(|k| ((value[k] - truth[k]) / k_sigma(k)).abs())
            .fold(0.0, f64::max)
    };
    let single = id
        .single_pass
        .as_ref()
        .expect("the single pass on the paper's run");
    let refined = id.refined.as_ref().unwrap();
    let z_single = worst_z(&single.value, &|k| single.sigma(k));
    let z_refined = worst_z(&refined.value, &|k| refined.sigma(k));
    assert!(
        z_single > 10.0,
        "single pass worst error/σ {z_single}: expected overconfident"
    );
    assert!(z_refined < 4.0, "refined worst error/σ {z_refined}");
}

/// A short run (10 h at 10 s, 37.6° N: `driftid simulate --seed 26 --latitude-deg 37.6 --hours
/// 10 --rate-s 10`) is more nonlinear for the smoother: its third Gauss–Newton iteration still
/// moved the estimate, and the innovations of the pass about the second gave NIS/3 1.47 and
/// Ljung–Box p 0 — a clean run refused as "does not explain the measurements". The iterations
/// now go on until a step moves no state by 0.01σ, and the fit is consistent.
#[test]
fn a_short_run_iterates_until_the_smoother_converges() {
    let mut sc = Scenario::paper();
    sc.seed = 26;
    sc.latitude_deg = 37.6;
    sc.hours = 10.0;
    sc.rate_s = 10.0;
    let sim = simulate(&sc);
    let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
    let site = Site::new(sc.latitude_deg, sc.gravity_mps2);
    let model = Model::new(
        site,
        &PAPER_EFFECTS,
        arw_deg2ph_to_rad2ps(1e-8),
        Propagation::default(),
    )
    .unwrap();
    let cfg = Config::default();
    let prep = prepare(site, &samples, &cfg).unwrap();
    let id = identify(&model, &prep, &cfg).unwrap();
    let conv = id.convergence.expect("the converged path ran");
    assert!(
        conv.converged && conv.iterations > cfg.smoother_iterations,
        "{conv:?}"
    );
    let check = host_tool::cli::identify::consistency_of(&id, &prep).unwrap();
    assert!(check.is_consistent(), "{:?}", check.failures);
    // Every coefficient within 3σ of the truth (the run is short: the 1σ are large, but honest).
    let best = id.best();
    let truth = sim.truth.coefficient_array();
    for k in 0..12 {
        let z = (best.value[k] - truth[k]) / best.sigma(k);
        assert!(z.abs() < 3.0, "{}: {z:.2} σ", id.params[k].name);
    }
}
