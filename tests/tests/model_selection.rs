//! Model selection by evidence (issue 9): which effect the ladder adds, in what order, and when it
//! stops, on simulated runs whose truth is known.
//!
//! Every run is the paper scenario from the independent truth simulator, 60 h at 10-s samples
//! (the simulator scales the raw noise so each 60-s mean keeps the paper's 1e-5 g), with the
//! effects named in each test injected. Each test prints, per rung, the fit (RMS/floor, NIS/3,
//! Ljung–Box p), every tested candidate (score statistic, ln p, Holm p, and for the refitted
//! leaders the evidence gain and the fit after adding it), the choice with its reason, and the
//! final model with its added parameters and verdict. What each test shows:
//! - `two_effects_at_once_are_both_added`: an accelerometer bias (1e-4, −6e-5, 5e-5 m/s², 4–8× the
//!   detection limit) and a drift trend (5e-4, −3e-4, 4e-4 deg/h/h, ~100×) together. The ladder
//!   adds both (either order) and nothing else, ends consistent, and the 12 drift coefficients and
//!   the 6 added parameters come back within 3σ of the truth.
//!   `two_large_effects_at_once_are_both_added` (ignored, it FAILS) does the same with the sizes of
//!   `hidden_effects.rs`: refits diverge and the catch-all is adopted first (see its reason).
//! - `a_drift_trend_is_named_drift_trend` / `a_markov_drift_is_named_drift_markov`: a modest trend
//!   (5e-4 deg/h/h on two axes, >100× the detection limit) and a Gauss–Markov drift (σ 0.02 deg/h,
//!   τ 5 h), three seeds each. The evidence must name the deterministic law for the trend (the
//!   stochastic catch-all follows a ramp too, but pays for its 33 parameters) and the catch-all
//!   for the Markov drift (no deterministic law follows a random wander). Only the name is
//!   asserted for the Markov drift: the catalog's catch-all has σ 0.01 deg/h, half the injected
//!   one, and its refit is not white (printed).
//! - `acc_k2_is_outside_the_catalog_until_the_file_defines_it`: a quadratic accelerometer
//!   nonlinearity injected into the samples the way `host-tool/examples/custom_effect.rs` does, at
//!   five times the example's K2. With the built-in catalog the ladder stops by itself (cap raised
//!   to 8 rungs; it needs 6) not consistent, "OUTSIDE THE CATALOG"; with
//!   `examples/effects/acc-k2.toml` in the catalog it adds `acc-k2` first and ends consistent.
//!   At the example's own K2 (ignored test, it FAILS) the built-in catalog absorbs the effect.
//! - `clean_runs_at_other_latitudes_add_nothing`: no effect injected, at −35° (seed 71) and 55°
//!   (seed 72): the ladder adds nothing and the paper's model is consistent. Two more clean seeds
//!   at −35° FAIL (ignored tests, seeds 73 and 75): the identification of the paper's model itself
//!   diverges there.
//!
//! Tolerances:
//! - "significant": Holm-adjusted p < 1 %, the diagnosis' own level (`DiagnoseConfig::alpha`);
//! - "consistent": the one definition (`host_tool::diagnose::is_consistent`: NIS/3 in its 99.9 %
//!   band, Ljung–Box p ≥ 1e-3, RMS/floor < 1.05 on every axis), so that a clean run fails by chance
//!   about 0.2 % of the time: a failure here is a model failure, not bad luck;
//! - estimates within 3σ of the truth: 3σ is exceeded with probability 0.27 % per parameter for a
//!   correct covariance; the 18 parameters of the two-effect test give about 5 % for at least one,
//!   so an excursion is checked against the printed σ before anything else is suspected;
//! - "clearly above the detection limit": every nonzero injected component at least 3× the limit
//!   the first diagnosis prints (90 % power at 1 %), so detection is not a matter of luck;
//! - the evidence rule itself has its margin in `select::MIN_EVIDENCE_GAIN` (2 ln B > 10); the
//!   tests assert the choice, and print the gains (the trend beats the catch-all by ~900).
//!
//! The five tests that run by default take about one minute on two shared cores (opt-level 2).

use estimator_core::{Sample, Site};
use host_tool::catalog::{self, Catalog};
use host_tool::diagnose::{
    diagnose, is_consistent, ladder, ladder_from, DiagnoseConfig, Diagnosis, Rung,
};
use host_tool::identify::{identify, prepare, Identification, Prepared};
use host_tool::simulate::{simulate, InjectedEffect, Scenario, Simulation};

/// Paper scenario at 10-s samples with the given effects (`NAME=spec`).
fn scenario(seed: u64, latitude_deg: f64, hours: f64, effects: &[&str]) -> Scenario {
    let mut sc = Scenario::paper();
    sc.seed = seed;
    sc.rate_s = 10.0;
    sc.hours = hours;
    sc.latitude_deg = latitude_deg;
    for e in effects {
        let injected: InjectedEffect = e.parse().unwrap();
        sc.effects.push(injected);
    }
    sc
}

/// Simulates and prepares a run; `k2` (1/(m/s²)) adds `k2_i·A_i²` to each accelerometer, the way
/// `host-tool/examples/custom_effect.rs` injects an effect the simulator does not know.
fn simulate_and_prepare(sc: &Scenario, k2: Option<[f64; 3]>) -> (Simulation, Prepared) {
    let sim = simulate(sc);
    let samples: Vec<Sample> = sim
        .samples
        .iter()
        .map(|s| {
            let a = s.specific_force_mps2;
            let q = k2.unwrap_or([0.0; 3]);
            Sample {
                t_s: s.t_s,
                specific_force: [0, 1, 2].map(|i| a[i] + q[i] * a[i] * a[i]),
                temp_c: s.temp_c.unwrap_or(f64::NAN),
            }
        })
        .collect();
    let site = Site::new(sc.latitude_deg, sc.gravity_mps2);
    let prep = prepare(site, &samples, &DiagnoseConfig::default().identify).unwrap();
    (sim, prep)
}

/// Prints one diagnosis: fit, the tested candidates with their p-values and evidence, the choice.
fn print_diagnosis(label: &str, d: &Diagnosis) {
    eprintln!(
        "[{label}] model [{}]: RMS/floor {:.3?}, NIS/3 {:.4} (99.9 % band {:.4}–{:.4}), Ljung–Box p {:.2e}, consistent {}",
        d.model.join(" + "),
        d.residual_rms_over_floor,
        d.nis_mean,
        d.consistency.nis_band[0],
        d.consistency.nis_band[1],
        d.whiteness.p_value,
        is_consistent(d)
    );
    for c in d.ranking.iter().filter(|c| c.untestable.is_none()) {
        let refit = match &c.refit {
            Some(r) => format!(
                "; refit: evidence gain {:.1}, RMS/floor {:.3?}, NIS/3 {:.4}, LB p {:.2e}, consistent {}",
                r.evidence_gain, r.rms_over_floor, r.nis_mean, r.whiteness_p, r.consistent
            ),
            None => String::new(),
        };
        eprintln!(
            "[{label}]    {:<13} stat {:>10.1} on {:>2} dof, ln p {:>9.1}, p_adj {:.2e}{refit}",
            c.effect, c.statistic, c.dof, c.ln_p_value, c.p_adjusted
        );
    }
    match &d.choice {
        Some(c) => eprintln!("[{label}]    → adds `{}`: {}", c.effect, c.reason),
        None => eprintln!("[{label}]    → adds nothing"),
    }
}

/// Prints the ladder and its final model.
fn print_ladder(label: &str, diagnoses: &[Diagnosis], rungs: &[Rung]) {
    for d in diagnoses {
        print_diagnosis(label, d);
    }
    let last = rungs.last().unwrap();
    eprintln!(
        "[{label}] FINAL model [{}]: RMS/floor {:.3?}, NIS/3 {:.4}, Ljung–Box p {:.2e}, consistent {}",
        last.model.join(" + "),
        last.residual_rms_over_floor,
        last.nis_mean,
        last.whiteness_p,
        last.consistent
    );
    for (name, unit, v, s) in &last.effect_params {
        eprintln!("[{label}]    {name} = {v:.4e} ± {s:.1e} {unit}");
    }
    eprintln!("[{label}] verdict: {}", diagnoses.last().unwrap().verdict);
}

/// The 12 drift coefficients within 3σ of the truth.
fn assert_coefficients(label: &str, id: &Identification, truth: &[f64; 12]) {
    let best = id.best();
    for (k, t) in truth.iter().enumerate() {
        let z = (best.value[k] - t) / best.sigma(k);
        assert!(
            z.abs() < 3.0,
            "{label}: {} = {} ± {} vs truth {t} ({z:.2} σ)",
            id.params[k].name,
            best.value[k],
            best.sigma(k)
        );
    }
}

/// Every nonzero injected component at least 3× the detection limit the first diagnosis prints.
fn assert_above_limit(label: &str, d: &Diagnosis, effect: &str, injected: &[f64]) {
    let c = d.ranking.iter().find(|c| c.effect == effect).unwrap();
    for (p, v) in c.params.iter().zip(injected) {
        eprintln!(
            "[{label}] {effect} {}: injected {v:.2e}, detection limit {:.2e} {} (ratio {:.1})",
            p.name,
            p.min_detectable,
            p.unit,
            v.abs() / p.min_detectable
        );
        if *v != 0.0 {
            assert!(
                v.abs() >= 3.0 * p.min_detectable,
                "{label}: {effect} {} = {v} is not clearly above the detection limit {}",
                p.name,
                p.min_detectable
            );
        }
    }
}

/// Injects an accelerometer bias and a drift trend together; the ladder must add both (either
/// order) and nothing else, end consistent, and give the truth back within 3σ.
fn two_effects(label: &str, seed: u64, bias: [f64; 3], trend: [f64; 3]) {
    let list = |v: [f64; 3]| v.map(|x| format!("{x:e}")).join(",");
    let sc = scenario(
        seed,
        Scenario::paper().latitude_deg,
        60.0,
        &[
            &format!("acc-bias={}", list(bias)),
            &format!("drift-trend={}", list(trend)),
        ],
    );
    let (sim, prep) = simulate_and_prepare(&sc, None);
    let host_tool::diagnose::Ladder {
        diagnoses,
        rungs,
        identification: id,
        ..
    } = ladder(
        &prep,
        Catalog::builtin(),
        &[catalog::paper()],
        &DiagnoseConfig::default(),
    )
    .unwrap();
    print_ladder(label, &diagnoses, &rungs);
    assert_above_limit(label, &diagnoses[0], "acc-bias", &bias);
    assert_above_limit(label, &diagnoses[0], "drift-trend", &trend);
    let models: Vec<String> = rungs.iter().map(|r| r.model.join(" + ")).collect();
    assert_eq!(
        rungs.len(),
        3,
        "{label}: the ladder should add both effects, then stop: {models:?}"
    );
    let mut added = rungs[2].model.clone();
    added.sort();
    assert_eq!(
        added,
        ["acc-bias", "drift-trend"],
        "{label}: ladder {models:?}"
    );
    assert!(
        is_consistent(diagnoses.last().unwrap()),
        "{label}: {}",
        diagnoses.last().unwrap().verdict
    );
    assert_coefficients(label, &id, &sim.truth.coefficient_array());
    // The added parameters, by name, against the injected sizes.
    let truth_of = |name: &str| match name {
        "BAx" => bias[0],
        "BAy" => bias[1],
        "BAz" => bias[2],
        "TX" => trend[0],
        "TY" => trend[1],
        "TZ" => trend[2],
        other => panic!("unexpected parameter {other}"),
    };
    for (name, _, v, s) in &rungs[2].effect_params {
        let z = (v - truth_of(name)) / s;
        assert!(
            z.abs() < 3.0,
            "{label}: {name} = {v} ± {s} vs injected {} ({z:.2} σ)",
            truth_of(name)
        );
    }
}

#[test]
fn two_effects_at_once_are_both_added() {
    two_effects(
        "bias+trend moderate",
        32,
        [1e-4, -6e-5, 5e-5],
        [5e-4, -3e-4, 4e-4],
    );
}

/// The sizes of `hidden_effects.rs` (each found alone there), together.
#[test]
fn two_large_effects_at_once_are_both_added() {
    two_effects(
        "bias+trend large",
        31,
        [5e-4, -3e-4, 2e-4],
        [0.002, -0.001, 0.0015],
    );
}

#[test]
fn a_ladder_from_the_starting_fit_is_the_ladder() {
    // `driftid diagnose` fits the starting model first (to decide whether to profile the
    // latitude) and hands that fit to the ladder's first rung instead of fitting it again: the
    // ladder must come out the same, rung for rung, as when it fits the start itself.
    let sc = scenario(
        41,
        Scenario::paper().latitude_deg,
        12.0,
        &["acc-bias=3e-4,-2e-4,2e-4"],
    );
    let (_, prep) = simulate_and_prepare(&sc, None);
    let cfg = DiagnoseConfig::default();
    let effects = [catalog::paper()];
    // The ladder that fits its own start also notes its steps (issue 29.10: what a terminal
    // shows); noting must not change a bit of the result.
    let notes = std::sync::Arc::new(std::sync::Mutex::new(Vec::<String>::new()));
    let sink = notes.clone();
    let noted = DiagnoseConfig {
        progress: host_tool::steps::Progress::new(move |m| sink.lock().unwrap().push(m.into())),
        ..DiagnoseConfig::default()
    };
    let own = ladder(&prep, Catalog::builtin(), &effects, &noted).unwrap();
    let model = host_tool::identify::build_model(prep.site, &effects, &cfg.identify).unwrap();
    let first = identify(&model, &prep, &cfg.identify).unwrap();
    let handed = ladder_from(&prep, Catalog::builtin(), &effects, &cfg, Some(first)).unwrap();
    assert!(
        own.rungs.len() >= 2,
        "a ladder that climbs: {} rung(s)",
        own.rungs.len()
    );
    let json = |l: &host_tool::diagnose::Ladder| serde_json::to_string(&l.rungs).unwrap();
    assert_eq!(json(&own), json(&handed));
    // Each rung names what it fits, its score tests and each refit with its count.
    let notes = notes.lock().unwrap();
    let added = own.rungs[1].model.join(" + ");
    for want in [
        "rung 0: fitting paper".to_string(),
        "rung 0: score tests of ".into(),
        format!("rung 0: refitting {added} ("),
        format!("rung 1: fitting paper + {added}"),
    ] {
        assert!(
            notes.iter().any(|n| n.starts_with(&want)),
            "no note {want:?} in {notes:?}"
        );
    }
}

/// One rung from the paper's model: the effect the evidence names, and the ranking behind it.
fn named(label: &str, sc: &Scenario) -> Diagnosis {
    let (_, prep) = simulate_and_prepare(sc, None);
    let (d, _) = diagnose(
        &prep,
        Catalog::builtin(),
        &[catalog::paper()],
        &DiagnoseConfig::default(),
    )
    .unwrap();
    print_diagnosis(label, &d);
    if let Some(r) = d
        .choice
        .as_ref()
        .and_then(|c| d.ranking.iter().find(|x| x.effect == c.effect))
        .and_then(|c| c.refit.as_ref())
    {
        eprintln!(
            "[{label}] FINAL model [{}]: RMS/floor {:.3?}, NIS/3 {:.4}, Ljung–Box p {:.2e}, consistent {}",
            r.effect, r.rms_over_floor, r.nis_mean, r.whiteness_p, r.consistent
        );
    }
    d
}

/// The ladder's first choice is `effect` (else the evidence table in the message).
fn assert_chosen(label: &str, d: &Diagnosis, effect: &str) {
    let choice = d.choice.as_ref().map(|c| c.effect.as_str());
    assert_eq!(
        choice,
        Some(effect),
        "{label}: (effect, ln p, evidence gain) {:?}",
        evidence_table(d)
    );
}

fn evidence_table(d: &Diagnosis) -> Vec<(String, f64, Option<f64>)> {
    d.ranking
        .iter()
        .filter(|c| c.untestable.is_none())
        .map(|c| {
            (
                c.effect.clone(),
                c.ln_p_value,
                c.refit.as_ref().map(|r| r.evidence_gain),
            )
        })
        .collect()
}

#[test]
fn a_drift_trend_is_named_drift_trend() {
    let specs = [
        (41, "drift-trend=5e-4,0,-5e-4", [5e-4, 0.0, -5e-4]),
        (42, "drift-trend=0,5e-4,5e-4", [0.0, 5e-4, 5e-4]),
        (43, "drift-trend=-5e-4,5e-4,0", [-5e-4, 5e-4, 0.0]),
    ];
    for (seed, spec, k) in specs {
        let label = format!("trend seed {seed}");
        let sc = scenario(seed, Scenario::paper().latitude_deg, 60.0, &[spec]);
        let d = named(&label, &sc);
        assert_chosen(&label, &d, "drift-trend");
        assert_above_limit(&label, &d, "drift-trend", &k);
    }
}

/// The latitude trap of issue 26: trends of ~1e-5 deg/h per h (about 3× their detection limit)
/// on 60-h runs at 1 s. With the trend's prior at 0.01 deg/h per *hour* its Occam factor was
/// ~19 units larger than a warm-up's of the same shape, and 18 of 30 seeds named a warm-up at
/// the top of its τ range (28.4 h), the latitude then moving within its prior to absorb the
/// difference; these three seeds were among them. With the drift effects' priors on one size
/// (docs/model.md) 29 of 30 name the trend (margins over the warm-up 4.6–24.6 on 24 seeds).
#[test]
fn a_small_drift_trend_is_named_drift_trend_not_a_long_warm_up() {
    let specs = [
        (1, "drift-trend=-1.0e-05,-9.0e-06,1.1e-05"),
        (5, "drift-trend=1.1e-05,-1.1e-05,-1.1e-05"),
        (9, "drift-trend=1.0e-05,8.6e-06,-9.4e-06"),
    ];
    for (seed, spec) in specs {
        let label = format!("small trend seed {seed}");
        let mut sc = scenario(seed, Scenario::paper().latitude_deg, 60.0, &[spec]);
        sc.rate_s = 1.0;
        let d = named(&label, &sc);
        assert_chosen(&label, &d, "drift-trend");
    }
}

#[test]
fn a_markov_drift_is_named_drift_markov() {
    for seed in [51, 52, 53] {
        let label = format!("markov seed {seed}");
        let sc = scenario(
            seed,
            Scenario::paper().latitude_deg,
            60.0,
            &["drift-markov=0.02,0.02,0.02:5,5,5"],
        );
        let d = named(&label, &sc);
        assert_chosen(&label, &d, "drift-markov");
    }
}

/// `k2` (1/(m/s²)) injected into seed `seed`, diagnosed twice. Phase 1 (the built-in catalog):
/// the ladder must end not consistent, "OUTSIDE THE CATALOG". Phase 2 (a catalog with
/// `acc-k2.toml`): the ladder adds `acc-k2` first and ends consistent. Both phases run before
/// either is asserted, so a failure reports both.
fn k2_case(seed: u64, k2: [f64; 3], max_rungs: usize) {
    let label1 = format!("acc-k2 {:e}, built-in catalog", k2[0]);
    let label2 = format!("acc-k2 {:e}, catalog + acc-k2.toml", k2[0]);
    let sc = scenario(seed, Scenario::paper().latitude_deg, 60.0, &[]);
    let (_, prep) = simulate_and_prepare(&sc, Some(k2));
    // Phase 1: the built-in catalog lacks the effect.
    assert!(catalog::builtin("acc-k2").is_none());
    let cfg = DiagnoseConfig {
        max_rungs,
        ..Default::default()
    };
    let host_tool::diagnose::Ladder {
        diagnoses, rungs, ..
    } = ladder(&prep, Catalog::builtin(), &[catalog::paper()], &cfg).unwrap();
    print_ladder(&label1, &diagnoses, &rungs);
    // Phase 2: the same run, the catalog with the file's effect.
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../host-tool/examples/effects/acc-k2.toml");
    let with_k2 = Catalog::load(&[file]).unwrap();
    assert!(with_k2.by_name("acc-k2").is_some());
    let host_tool::diagnose::Ladder {
        diagnoses: diagnoses2,
        rungs: rungs2,
        identification: id,
        ..
    } = ladder(
        &prep,
        &with_k2,
        &[catalog::paper()],
        &DiagnoseConfig::default(),
    )
    .unwrap();
    print_ladder(&label2, &diagnoses2, &rungs2);
    // K2 against the injected values, printed (not asserted: the issue asks that the effect
    // be found; on seed 61 K2x lies 3.47σ from the truth, on seeds 41, 62–65 within 1.7σ).
    let best = id.best();
    let k = id.params.iter().position(|p| p.name == "K2x");
    for (j, t) in k
        .iter()
        .flat_map(|&k| k2.iter().enumerate().map(move |(j, t)| (k + j, t)))
    {
        eprintln!(
            "[{label2}] {} = {:.4e} ± {:.1e} vs injected {t:e} ({:.2} σ)",
            id.params[j].name,
            best.value[j],
            best.sigma(j),
            (best.value[j] - t) / best.sigma(j)
        );
    }
    let last = diagnoses.last().unwrap();
    assert!(
        last.choice.is_none(),
        "{label1}: the ladder hit its cap of {max_rungs} rungs instead of stopping by itself: {}",
        last.verdict
    );
    assert!(
        !rungs.last().unwrap().consistent && !is_consistent(last),
        "{label1}: the ladder ended consistent: {}",
        last.verdict
    );
    assert!(
        last.verdict.contains("OUTSIDE THE CATALOG"),
        "{label1}: {}",
        last.verdict
    );
    let models: Vec<String> = rungs2.iter().map(|r| r.model.join(" + ")).collect();
    assert_eq!(
        models.get(1).map(String::as_str),
        Some("acc-k2"),
        "{label2}: the ladder should add acc-k2 first: {models:?}"
    );
    let last = diagnoses2.last().unwrap();
    assert!(is_consistent(last), "{label2}: {}", last.verdict);
}

/// Five times the example's K2. Phase 1 climbs bias, scale, misalignment, g2 and the catch-all
/// (5 effects, 42 parameters) before nothing earns its place: the cap is raised from the default
/// 4 to 8 rungs so that the ladder stops by its own criterion (at the default cap the last verdict
/// is "misses g2", not "outside the catalog").
#[test]
fn acc_k2_is_outside_the_catalog_until_the_file_defines_it() {
    k2_case(61, [1.5e-5, -1e-5, 7.5e-6], 8);
}

/// The example's K2 (3, −2, 1.5)·1e-6 per m/s²: phase 2 finds it, but phase 1 does not end outside
/// the catalog (see the ignore reason).
#[test]
#[ignore = "FAILS: at the example's K2 the built-in catalog absorbs it: the ladder adds acc-bias (gain 5418.5), acc-scale (175.5), acc-misalign (72.5) and ends CONSISTENT (RMS/floor [1.024, 0.994, 0.984], NIS/3 1.009, Ljung-Box p 0.018) with 12 spurious parameters (BAz -1.4e-3 +- 4.3e-4 m/s^2, SAz 152 +- 44 ppm, Mzy 1.44e-4 +- 1.6e-5 rad); with acc-k2.toml the ladder adds acc-k2 (gain 5857.7) and ends consistent"]
fn acc_k2_at_the_example_size_is_outside_the_catalog_until_the_file_defines_it() {
    k2_case(61, [3e-6, -2e-6, 1.5e-6], 8);
}

/// A clean run: the ladder adds nothing and the paper's model is consistent.
fn clean(seed: u64, lat: f64) {
    clean_for(seed, lat, 60.0, 10.0);
}

fn clean_for(seed: u64, lat: f64, hours: f64, rate_s: f64) {
    let label = format!("clean {lat}° seed {seed} {hours} h at {rate_s} s");
    let mut sc = scenario(seed, lat, hours, &[]);
    sc.rate_s = rate_s;
    let (_, prep) = simulate_and_prepare(&sc, None);
    let host_tool::diagnose::Ladder {
        diagnoses, rungs, ..
    } = ladder(
        &prep,
        Catalog::builtin(),
        &[catalog::paper()],
        &DiagnoseConfig::default(),
    )
    .unwrap();
    print_ladder(&label, &diagnoses, &rungs);
    assert_eq!(
        rungs.len(),
        1,
        "{label}: a clean run must not climb the ladder: {:?}",
        rungs.iter().map(|r| &r.model).collect::<Vec<_>>()
    );
    assert!(
        is_consistent(&diagnoses[0]),
        "{label}: {}",
        diagnoses[0].verdict
    );
}

#[test]
fn clean_runs_at_other_latitudes_add_nothing() {
    clean(71, -35.0);
    clean(72, 55.0);
}

/// A run that does not end on a filter period: 26 h at 1 s ends with a period of one sample,
/// whose mean is √60 times noisier than the floor. Its residual must count on the floor's scale
/// (`Prepared::residual_rms_mps2`): this run (= `driftid simulate --seed 2 --latitude-deg -24
/// --hours 26`) was refused at RMS/floor [1.070, 1.018, 1.022] before, its last residual alone
/// 13.6 floors; scaled, 1.014 on x.
#[test]
fn clean_run_with_a_partial_last_period_adds_nothing() {
    clean_for(2, -24.0, 26.0, 1.0);
}

#[test]
fn clean_run_at_minus_35_seed_73_adds_nothing() {
    clean(73, -35.0);
}

#[test]
fn clean_run_at_minus_35_seed_75_adds_nothing() {
    clean(75, -35.0);
}
