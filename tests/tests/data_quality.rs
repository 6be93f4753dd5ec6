//! Flawed recordings: every fault kind is found and named; a repairable one is repaired and the
//! coefficients stay within 3σ of the truth; an unrepairable one is refused (or flagged as not
//! trusted); clean recordings at many latitudes, both hemispheres, produce no finding at all.
//!
//! Faults are applied to recordings of the independent truth simulator, the way real recordings
//! go wrong (a glitch, a stuck or dead channel, dropouts, NaN rows, a time column in ms, outputs
//! in g, wrong metadata, a tilted start, an inverted or swapped axis, rounding, a bias step).
//! Tolerance "within 3σ": each of the 12 coefficients' error over its own 1σ; on clean data the
//! errors are N(0, 1) in those units (README: NEES in band), so 3σ fails ~3 % of single
//! coefficients by chance — the runs use fixed seeds whose clean errors are below 2.4σ.

use estimator_core::{Sample, Site};
use host_tool::catalog;
use host_tool::identify::{identify, prepare, Config, Prepared};
use host_tool::quality::{Action, Refusal};
use host_tool::simulate::{simulate, Scenario};

fn run(
    seed: u64,
    latitude_deg: f64,
    hours: f64,
    rate_s: f64,
    tilt_deg: [f64; 3],
) -> (Scenario, Vec<Sample>) {
    let mut sc = Scenario::paper();
    sc.seed = seed;
    sc.latitude_deg = latitude_deg;
    sc.accel_sigma_mps2 = 1e-5 * sc.gravity();
    sc.hours = hours;
    sc.rate_s = rate_s;
    sc.initial_orientation_deg = tilt_deg;
    let sim = simulate(&sc);
    let samples = sim.samples.iter().map(Sample::from).collect();
    (sc, samples)
}

/// A change applied to a copy of the clean samples.
type Mutation = Box<dyn Fn(&mut Vec<Sample>)>;

fn site_of(sc: &Scenario) -> Site {
    Site::new(sc.latitude_deg, sc.gravity_mps2)
}

/// Identifies with the paper's model and returns the worst |error|/σ over the 12 coefficients.
fn worst_err_over_sigma(sc: &Scenario, prep: &Prepared) -> f64 {
    let effects = [catalog::paper()];
    let cfg = Config::default();
    let model = host_tool::cli::common::build_model(prep.site, &effects, &cfg).unwrap();
    let id = identify(&model, prep, &cfg).unwrap();
    let best = id.best();
    (0..12)
        .map(|k| ((best.value[k] - sc.coefficients[k]) / best.sigma(k)).abs())
        .fold(0.0, f64::max)
}

fn kinds(prep: &Prepared) -> Vec<&'static str> {
    prep.findings.iter().map(|f| f.kind.name()).collect()
}

fn refusal(site: Site, samples: &[Sample]) -> Refusal {
    match prepare(site, samples, &Config::default()) {
        Ok(p) => panic!("expected a refusal, got findings {:?}", kinds(&p)),
        Err(e) => match e.downcast::<Refusal>() {
            Ok(r) => r,
            Err(e) => panic!("expected a refusal, got {e:#}"),
        },
    }
}

#[test]
fn clean_recordings_produce_no_finding() {
    // 32 seeds over 8 latitudes, both hemispheres; 24 h at 2 s (43 201 samples each).
    let lats = [-62.0, -39.1, -21.0, -8.0, 12.0, 30.0, 47.5, 71.0];
    let mut alarms = vec![];
    for seed in 0..32u64 {
        let lat = lats[seed as usize % lats.len()];
        let (sc, samples) = run(100 + seed, lat, 24.0, 2.0, [0.0; 3]);
        let prep = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
        if !prep.findings.is_empty() {
            alarms.push((seed, lat, kinds(&prep)));
        }
    }
    eprintln!(
        "clean controls: {} of 32 with a finding: {alarms:?}",
        alarms.len()
    );
    assert!(alarms.is_empty(), "false alarms on clean data: {alarms:?}");
}

/// Clean runs of one shape: the seeds (of `seeds`) whose screening reports anything, with the
/// findings. `shape(seed)` gives (latitude, hours, sample interval, samples dropped at the start);
/// the screening (`quality::screen`, what every command runs first) is called directly: the
/// identification is not needed to see a false alarm, and the sweep must stay fast.
fn false_alarms(
    seeds: std::ops::Range<u64>,
    shape: impl Fn(u64) -> (f64, f64, f64, usize),
) -> Vec<(u64, Vec<String>)> {
    let mut out = vec![];
    for seed in seeds {
        let (lat, hours, rate_s, skip) = shape(seed);
        let (sc, samples) = run(seed, lat, hours, rate_s, [0.0; 3]);
        let screened = host_tool::quality::screen(site_of(&sc), &samples[skip..], 60.0)
            .unwrap_or_else(|r| panic!("seed {seed}: clean run refused: {r}"));
        if !screened.findings.is_empty() {
            out.push((seed, screened.findings.iter().map(|f| f.line()).collect()));
        }
    }
    out
}

/// Issue 27: at most 1 false alarm in 100 clean seeds (the issue's ≤ 1 %). With 8σ thresholds
/// a correctly weighted screening should give none; 1 is allowed so that a single rare
/// coincidence (an 8σ event has P ≈ 1e-15, but the robust scales are estimated) does not make
/// the test flaky, while the bug this guards against gave 5–9 per 100.
fn assert_at_most_one_in(what: &str, seeds: u64, alarms: &[(u64, Vec<String>)]) {
    eprintln!(
        "{what}: {} of {seeds} clean seeds with a finding: {alarms:?}",
        alarms.len()
    );
    assert!(
        alarms.len() * 100 <= seeds as usize,
        "{what}: {} false alarms in {seeds} clean seeds: {alarms:?}",
        alarms.len()
    );
}

#[test]
fn no_false_alarm_at_the_partial_last_period_default_shape() {
    // The default scenario's shape (1 s, 39.1° N, a whole number of hours: the last 60-s
    // period holds one sample, t = end), 12 h instead of 60 to stay fast: the false alarm came
    // from the last four means, whatever the length. Before the fix 5 of 60 default 60-h runs
    // (seeds 7, 12, 51, 54, 56) reported a "step" at the end.
    let alarms = false_alarms(0..100, |_| (39.1, 12.0, 1.0, 0));
    assert_at_most_one_in("1 s, 12 h, 39.1° N", 100, &alarms);
}

#[test]
fn no_false_alarm_at_the_partial_last_period_10_hz() {
    // 10 Hz: the last period's one sample is √600 ≈ 24× noisier than a full mean.
    let alarms = false_alarms(1000..1100, |_| (39.1, 3.0, 0.1, 0));
    assert_at_most_one_in("0.1 s, 3 h, 39.1° N", 100, &alarms);
}

#[test]
fn no_false_alarm_at_the_partial_last_period_other_latitudes() {
    // Both hemispheres, near the equator and the pole (the cone, and so the gravity signal
    // the third differences must remove, changes with latitude).
    let lats = [-62.0, -21.0, 5.0, 71.0];
    let alarms = false_alarms(2000..2100, |s| (lats[s as usize % 4], 12.0, 1.0, 0));
    assert_at_most_one_in("1 s, 12 h, latitudes -62/-21/5/71", 100, &alarms);
}

#[test]
fn no_false_alarm_at_partial_periods_odd_durations() {
    // Odd durations: + 1 sample (the last period holds 2), 11.99 h (43 164 s: 25 in the last),
    // + 37 s, and a recording that starts 23 s into its first period (a partial first one).
    let alarms = false_alarms(3000..3100, |s| match s % 4 {
        0 => (39.1, 12.0 + 1.0 / 3600.0, 1.0, 0),
        1 => (39.1, 11.99, 1.0, 0),
        2 => (39.1, 12.0 + 37.0 / 3600.0, 1.0, 0),
        _ => (39.1, 12.0, 1.0, 23),
    });
    assert_at_most_one_in(
        "1 s, odd durations and a partial first period",
        100,
        &alarms,
    );
}

#[test]
fn repairable_faults_are_repaired_and_the_estimate_holds() {
    let (sc, clean) = run(7, 39.1, 30.0, 1.0, [0.0; 3]);
    let site = site_of(&sc);
    let base = prepare(site, &clean, &Config::default()).unwrap();
    assert!(base.findings.is_empty(), "{:?}", kinds(&base));
    let clean_worst = worst_err_over_sigma(&sc, &base);
    assert!(clean_worst < 3.0, "clean run itself: {clean_worst}");

    type Fault = (
        &'static str,
        &'static str,
        Box<dyn Fn(&mut Vec<Sample>, &mut Site)>,
    );
    let faults: Vec<Fault> = vec![
        (
            "one spike of +500 m/s^2",
            "glitch",
            Box::new(|s, _| s[40_000].specific_force[1] += 500.0),
        ),
        (
            "25 glitches of 0.01–0.2 m/s^2",
            "glitch",
            Box::new(|s, _| {
                for k in 0..25 {
                    let i = 3_000 + k * 4_111;
                    s[i].specific_force[k % 3] += if k % 2 == 0 {
                        0.01 + 0.007 * k as f64
                    } else {
                        -0.05
                    };
                }
            }),
        ),
        (
            "x stuck for 10 000 samples",
            "stuck",
            Box::new(|s, _| {
                let v = s[50_000].specific_force[0];
                for x in &mut s[50_000..60_000] {
                    x.specific_force[0] = v;
                }
            }),
        ),
        (
            "an hour of zeros on z",
            "stuck",
            Box::new(|s, _| {
                for x in &mut s[70_000..73_600] {
                    x.specific_force[2] = 0.0;
                }
            }),
        ),
        (
            "all-zero dropouts",
            "dropout",
            Box::new(|s, _| {
                for k in 0..10 {
                    s[5_000 + 9_000 * k].specific_force = [0.0; 3];
                }
            }),
        ),
        (
            "NaN values",
            "non-finite",
            Box::new(|s, _| {
                for k in 0..10 {
                    s[7_000 + 8_000 * k].specific_force[k % 3] = f64::NAN;
                }
            }),
        ),
        (
            "time column in milliseconds",
            "time-units",
            Box::new(|s, _| s.iter_mut().for_each(|x| x.t_s *= 1000.0)),
        ),
        (
            "outputs in g",
            "units-g",
            Box::new(|s, _| {
                s.iter_mut()
                    .for_each(|x| x.specific_force.iter_mut().for_each(|v| *v /= 9.80665))
            }),
        ),
        (
            "metadata gravity 9.70 for 9.80",
            "gravity-mismatch",
            Box::new(|_, site| site.gravity_mps2 = 9.70),
        ),
    ];
    for (what, kind, apply) in faults {
        let mut s = clean.clone();
        let mut st = site;
        apply(&mut s, &mut st);
        let prep = prepare(st, &s, &Config::default()).unwrap_or_else(|e| panic!("{what}: {e:#}"));
        let found = kinds(&prep);
        assert!(
            found.contains(&kind),
            "{what}: expected `{kind}`, found {found:?}"
        );
        assert!(
            prep.findings.iter().all(|f| matches!(
                f.action,
                Action::Repaired | Action::Rejected | Action::Noted
            )),
            "{what}: {:?}",
            prep.findings
        );
        let worst = worst_err_over_sigma(&sc, &prep);
        eprintln!("{what}: {found:?}, worst |err|/σ {worst:.2} (clean {clean_worst:.2})");
        assert!(worst < 3.0, "{what}: worst |error|/σ = {worst:.2}");
    }
}

#[test]
fn a_tilted_start_gives_the_coefficients_of_a_level_one() {
    // The platform 0.1° and 2° off level at the start, the recording saying nothing about it.
    for tilt in [[0.1, 0.0, 0.0], [1.2, -1.6, 0.0]] {
        let (sc, samples) = run(3, 39.1, 30.0, 1.0, tilt);
        let prep = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
        assert_eq!(kinds(&prep), ["initial-tilt"], "{tilt:?}");
        let worst = worst_err_over_sigma(&sc, &prep);
        eprintln!("tilt {tilt:?}: worst |err|/σ {worst:.2}");
        assert!(worst < 3.0, "tilt {tilt:?}: worst |error|/σ = {worst:.2}");
    }
}

#[test]
fn unrepairable_faults_are_refused_or_not_trusted() {
    let (sc, clean) = run(11, 39.1, 12.0, 1.0, [0.0; 3]);
    let site = site_of(&sc);
    let refused: Vec<(&str, &str, Mutation)> = vec![
        (
            "dead sensor",
            "dead-axis",
            Box::new(|s| s.iter_mut().for_each(|x| x.specific_force = [0.0; 3])),
        ),
        (
            "inverted z",
            "initial-orientation",
            Box::new(|s| s.iter_mut().for_each(|x| x.specific_force[2] *= -1.0)),
        ),
        (
            "x and z swapped",
            "initial-orientation",
            Box::new(|s| s.iter_mut().for_each(|x| x.specific_force.swap(0, 2))),
        ),
        (
            // A left-handed frame turns as in the other hemisphere (it used to be named a
            // latitude of −39.1, and that rerun was 64 136σ off).
            "y written with its sign flipped",
            "other-hemisphere",
            Box::new(|s| s.iter_mut().for_each(|x| x.specific_force[1] *= -1.0)),
        ),
        (
            "time column in days",
            "time-units",
            Box::new(|s| s.iter_mut().for_each(|x| x.t_s /= 86_400.0)),
        ),
    ];
    for (what, kind, apply) in refused {
        let mut s = clean.clone();
        apply(&mut s);
        let r = refusal(site, &s);
        assert!(
            r.findings
                .iter()
                .any(|f| f.kind.name() == kind && f.action == Action::Refused),
            "{what}: {r}"
        );
        eprintln!("{what}: {r}");
    }
    // Rounded to 0.01 m/s^2 (13× the raw noise): the noise floor does not collapse, the
    // estimate is computed but flagged.
    let mut s = clean.clone();
    s.iter_mut().for_each(|x| {
        x.specific_force
            .iter_mut()
            .for_each(|v| *v = (*v / 0.01).round() * 0.01)
    });
    let prep = prepare(site, &s, &Config::default()).unwrap();
    assert!(kinds(&prep).contains(&"quantization"), "{:?}", kinds(&prep));
    assert!(!prep.untrusted_reasons().is_empty());
    assert!(
        prep.floor_mps2()
            .iter()
            .all(|f| *f >= 0.01 / 12f64.sqrt() * 0.99),
        "{:?}",
        prep.floor_mps2()
    );
    // A bias step of 2e-3 m/s^2 (20× the floor of a 60-s mean) on y halfway: issue 27 made it
    // a repair (`acc-bias-step`, sized and the later samples corrected), no longer an
    // unrepaired `step` (a_bias_step_is_found_sized_and_repaired covers it in detail).
    let mut s = clean.clone();
    let half = s.len() / 2;
    s[half..]
        .iter_mut()
        .for_each(|x| x.specific_force[1] += 2e-3);
    let prep = prepare(site, &s, &Config::default()).unwrap();
    assert_eq!(kinds(&prep), ["acc-bias-step"], "{:?}", prep.findings);
    assert!(prep.untrusted_reasons().is_empty());
    // A step of 2e-2 m/s^2, 26× the raw noise: the samples at the jump depart from their
    // neighbours' line and are rejected as glitches, which tags the step's window off the
    // grid; the step must still be found (and repaired), not hidden by it.
    let mut s = clean.clone();
    s[half..]
        .iter_mut()
        .for_each(|x| x.specific_force[1] += 2e-2);
    let prep = prepare(site, &s, &Config::default()).unwrap();
    assert!(
        kinds(&prep).contains(&"acc-bias-step") && !kinds(&prep).contains(&"step"),
        "{:?}",
        prep.findings
    );
    assert!(prep.untrusted_reasons().is_empty());
}

/// The latitude a `latitude` finding names (the number after "latitude "), deg.
fn named_latitude(f: &host_tool::quality::Finding) -> f64 {
    f.message
        .split("latitude ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no latitude in: {}", f.message))
}

#[test]
fn a_wrong_metadata_latitude_is_named_with_the_datas_latitude() {
    let (sc, samples) = run(5, 39.1, 30.0, 10.0, [0.0; 3]);
    // 30°: its round trip through radians is 29.999999999999996, which the message once quoted.
    let wrong = Site::new(30.0, sc.gravity_mps2);
    let prep = prepare(wrong, &samples, &Config::default()).unwrap();
    let f =
        host_tool::diagnose::latitude::check(&prep, &[catalog::paper()], &Config::default(), &[])
            .expect("the latitude is named");
    assert_eq!(f.kind.name(), "latitude");
    eprintln!("{}", f.message);
    assert!(
        f.message.contains("the metadata says 30 deg"),
        "the metadata's latitude as given: {}",
        f.message
    );
    // The estimate in the message must be within 0.05° of the truth (its 1σ is ~0.002° on 30 h).
    let est = named_latitude(&f);
    assert!((est - 39.1).abs() < 0.05, "{est}");
    // And the right latitude gives no such finding.
    let right = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
    assert!(host_tool::diagnose::latitude::check(
        &right,
        &[catalog::paper()],
        &Config::default(),
        &[]
    )
    .is_none());
}

#[test]
fn a_metadata_latitude_with_the_wrong_sign_is_named() {
    // South for north: gravity turns the other way round, which a left-handed frame (an axis
    // flipped) would do too, so the screening refuses it naming both, with the data's latitude
    // (within 5°: the paper's drift tilts the circle gravity sweeps by a few degrees).
    let (sc, samples) = run(6, 39.1, 30.0, 10.0, [0.0; 3]);
    let wrong = Site::new(-39.1, sc.gravity_mps2);
    let r = refusal(wrong, &samples);
    let f = r
        .findings
        .iter()
        .find(|f| f.kind.name() == "other-hemisphere" && f.action == Action::Refused)
        .unwrap_or_else(|| panic!("{r}"));
    assert!(
        f.message.contains("not -39.1° as stated")
            && f.message.contains("sign is wrong")
            && f.message.contains("left-handed"),
        "{}",
        f.message
    );
    let seen: f64 = f.message["gravity turns in the platform frame as at latitude ".len()..]
        .split('°')
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{}", f.message));
    assert!((seen - 39.1).abs() < 5.0, "{seen}");
}

#[test]
fn a_wrong_latitude_is_named_from_a_start_in_the_polar_chart() {
    // A stated start whose daily turn calls for the polar chart, whose angles depend on the
    // latitude: the profile must move the start's attitude, not its angles, to each latitude it
    // tries (it once refitted every other latitude from another attitude, and named none). 33° is
    // within the window around the metadata; 20° only in the one around gravity's latitude.
    let deg = [0.0, 60.0, 0.0];
    let (sc, samples) = run(7, 39.1, 30.0, 10.0, deg);
    let theta0 = deg.map(f64::to_radians);
    for wrong in [33.0, 20.0] {
        let site = Site::new(wrong, sc.gravity_mps2);
        let prep =
            host_tool::identify::prepare_oriented(site, &samples, &Config::default(), theta0)
                .unwrap();
        assert_eq!(prep.site.chart, estimator_core::frames::Chart::Polar);
        let f = host_tool::diagnose::latitude::check(
            &prep,
            &[catalog::paper()],
            &Config::default(),
            &[],
        )
        .unwrap_or_else(|| panic!("metadata {wrong}: the latitude is named"));
        let est = named_latitude(&f);
        // Within 0.05° of the truth (its 1σ is ~0.003° on 30 h at 10 s).
        assert!((est - 39.1).abs() < 0.05, "metadata {wrong}: {est}");
    }
}

#[test]
fn a_stated_initial_orientation_is_the_models_start() {
    // The platform set at (30°, −20°, 45°) before the run, as the recording's metadata states:
    // identified from there, every coefficient within 3σ of the truth, no finding.
    let deg = [30.0, -20.0, 45.0];
    let (sc, samples) = run(3, 39.1, 30.0, 10.0, deg);
    let theta0 = deg.map(f64::to_radians);
    let prep =
        host_tool::identify::prepare_oriented(site_of(&sc), &samples, &Config::default(), theta0)
            .unwrap();
    assert!(prep.findings.is_empty(), "{:?}", kinds(&prep));
    let worst = worst_err_over_sigma(&sc, &prep);
    eprintln!("orientation {deg:?}: worst |err|/σ {worst:.2}");
    assert!(worst < 3.0, "worst |error|/σ = {worst:.2}");
    // Read without the stated orientation, the start is estimated from the data (not refused)
    // and said so (tests/tests/orientation.rs checks that estimate).
    let unstated = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
    assert!(
        unstated
            .findings
            .iter()
            .any(|f| f.kind.name() == "initial-orientation" && f.action == Action::Repaired),
        "{:?}",
        kinds(&unstated)
    );
}

/// A clean run of the paper's scenario (`run`) with data faults (`driftid simulate --fault`
/// syntax) applied to its samples.
fn run_with_faults(seed: u64, hours: f64, faults: &[&str]) -> (Scenario, Vec<Sample>) {
    let mut sc = Scenario::paper();
    sc.seed = seed;
    sc.hours = hours;
    let mut sim = simulate(&sc);
    for f in faults {
        let fault: host_tool::simulate::Fault = f.parse().unwrap();
        assert!(fault.apply(&mut sim.samples) > 0, "{f} changed nothing");
    }
    (sc, sim.samples.iter().map(Sample::from).collect())
}

#[test]
fn a_sensor_pinned_at_its_rails_is_named_saturated_excluded_and_trusted() {
    // Issue 27: x clipped at ±7 m/s² (seed 3, 30 h: x swings over ±7.3 m/s² as gravity turns
    // in the platform frame, so it reaches each rail for hours, a fifth of the run in all) was
    // reported as steps, a gravity mismatch and a misfit. Now: one `saturated` finding per
    // stretch, each naming its time range, the samples excluded, nothing unrepaired, and the
    // coefficients within 3σ of the truth (a clean run's worst is ~1.2σ for this seed's
    // family: 3σ is the file's bound, see the top).
    let (sc, samples) = run_with_faults(3, 30.0, &["saturate=x,7,0,30"]);
    let pinned: Vec<f64> = samples
        .iter()
        .filter(|s| s.specific_force[0].abs() == 7.0)
        .map(|s| s.t_s)
        .collect();
    let prep = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
    let sat: Vec<_> = prep
        .findings
        .iter()
        .filter(|f| f.kind.name() == "saturated")
        .collect();
    eprintln!("{:#?}", prep.findings);
    assert!(
        sat.len() >= 2,
        "both rails (+7 near 6 h and 29 h, -7 near 18 h) named: {:?}",
        kinds(&prep)
    );
    assert!(
        sat.iter().any(|f| f.message.contains("+7"))
            && sat.iter().any(|f| f.message.contains("-7"))
    );
    for f in &prep.findings {
        assert!(
            matches!(f.action, Action::Rejected | Action::Noted),
            "only excluded or noted, nothing else: {}",
            f.line()
        );
    }
    // Every pinned reading lies in a reported range.
    for t in &pinned {
        assert!(
            sat.iter()
                .any(|f| f.start_s.unwrap() <= *t && *t <= f.end_s.unwrap()),
            "pinned reading at {t} s outside every saturated range"
        );
    }
    let worst = worst_err_over_sigma(&sc, &prep);
    eprintln!("worst |error|/σ {worst:.2} after excluding the saturation");
    assert!(
        worst < 3.0,
        "worst |error|/σ {worst:.2} after excluding the saturation"
    );
}

#[test]
fn a_short_burst_is_a_disturbance_excluded_not_a_step() {
    // Issue 27: 60 s of +0.3 m/s² on y was reported as a "step" (not repaired, exit 3). The
    // level before and after agree, so it is a disturbance: its filter periods are excluded
    // (action rejected), the finding covers the burst, and the estimate stands (within 3σ).
    let (sc, samples) = run_with_faults(3, 30.0, &["burst=y,0.3,12.01,60"]);
    let prep = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
    eprintln!("{:#?}", prep.findings);
    assert!(!kinds(&prep).contains(&"step"), "{:?}", kinds(&prep));
    let d: Vec<_> = prep
        .findings
        .iter()
        .filter(|f| f.kind.name() == "disturbance")
        .collect();
    assert_eq!(d.len(), 1, "{:?}", kinds(&prep));
    assert_eq!(d[0].action, Action::Rejected);
    assert!(d[0].message.contains("axis y"), "{}", d[0].message);
    // The burst is 43 236–43 295 s; the excluded periods (mean times given) cover it to within
    // a period.
    let (a, b) = (d[0].start_s.unwrap(), d[0].end_s.unwrap());
    assert!(a - 60.0 <= 43_236.0 && 43_295.0 <= b + 60.0, "{a}–{b}");
    // No measurement left inside the burst.
    assert!(prep
        .measurements
        .iter()
        .all(|m| !(43_236.0..43_296.0).contains(&m.t_s)));
    for f in &prep.findings {
        assert!(matches!(f.action, Action::Rejected), "{}", f.line());
    }
    let worst = worst_err_over_sigma(&sc, &prep);
    eprintln!("worst |error|/σ {worst:.2} after excluding the burst");
    assert!(
        worst < 3.0,
        "worst |error|/σ {worst:.2} after excluding the burst"
    );
}

#[test]
fn a_fifteen_minute_disturbance_is_one_disturbance_not_two_steps() {
    // 15 min of +0.01 m/s² on y at 5 h: its start and its end are two events of the step check
    // (each a level shift on its own); together the level comes back, so one `disturbance`
    // covering the 15 periods is excluded. Before the events were joined: two `step`s, exit 3.
    let (sc, samples) = run_with_faults(3, 10.0, &["burst=y,0.01,5,900"]);
    let prep = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
    assert_eq!(kinds(&prep), ["disturbance"], "{:#?}", prep.findings);
    let f = &prep.findings[0];
    // Periods 5.0–5.25 h (mean times 18 029.5 … 18 869.5 s): all of them, not more than one extra
    // on either side.
    let (a, b) = (f.start_s.unwrap(), f.end_s.unwrap());
    assert!(
        (17_960.0..=18_030.0).contains(&a) && (18_860.0..=18_930.0).contains(&b),
        "{a}–{b}"
    );
}

/// Issue 27 item 2: the y accelerometer's bias jumps by 1e-3 m/s² at 30 h of the default 60-h
/// run (10× the 1σ of a 60-s mean; 2.3× under the third differences' 8σ, so it went unseen and
/// the ladder named the wrong physics). Found by the local level-shift scan (6σ), sized on ±6 h
/// of means, the later samples corrected: `acc-bias-step` (repaired) with its time and size,
/// and the coefficients within 3σ of the truth.
#[test]
fn a_bias_step_is_found_sized_and_repaired() {
    let (sc, samples) = run_with_faults(5, 60.0, &["step=y,1e-3,30"]);
    let prep = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
    assert_eq!(kinds(&prep), ["acc-bias-step"], "{:#?}", prep.findings);
    let f = &prep.findings[0];
    assert_eq!(f.action, Action::Repaired);
    assert!(f.message.starts_with("axis y:"), "{}", f.message);
    // The time to within one filter period (the window holding the jump is left out).
    let t = f.start_s.unwrap();
    assert!((t - 108_000.0).abs() <= 60.0, "t = {t}");
    // The size ("steps by +9.853e-4 ± 3.1e-5"): within 3σ of 1e-3.
    let (size, sd) = {
        let m = &f.message;
        let i = m.find("steps by ").unwrap() + 9;
        let rest: Vec<&str> = m[i..].split_whitespace().collect();
        (
            rest[0].parse::<f64>().unwrap(),
            rest[2].parse::<f64>().unwrap(),
        )
    };
    eprintln!("size {size:e} ± {sd:e}");
    assert!((size - 1e-3).abs() < 3.0 * sd, "size {size} ± {sd}");
    let worst = worst_err_over_sigma(&sc, &prep);
    eprintln!("worst |error|/σ {worst:.2} after the repair");
    assert!(worst < 3.0, "worst |error|/σ {worst:.2}");
}

/// At a filter period shorter than a minute (`--period-s 1`) the bias-step search runs on
/// 60-s means (sized on ±6 h of 1-s means, a 24-h run's search took 60 s, 200 s at 60 h,
/// growing with the square of the run): the step is found with the same size and 1σ as at the
/// default period, digit for digit (the same means are searched), and the repair leaves out the
/// 60-s window holding the jump.
#[test]
fn a_bias_step_is_searched_in_minute_means_at_a_one_second_period() {
    let (sc, samples) = run_with_faults(5, 60.0, &["step=y,4e-4,30"]);
    let at = |period_s: f64| {
        let cfg = Config {
            period_s,
            ..Config::default()
        };
        prepare(site_of(&sc), &samples, &cfg).unwrap()
    };
    let (p60, p1) = (at(60.0), at(1.0));
    assert_eq!(kinds(&p1), ["acc-bias-step"], "{:#?}", p1.findings);
    let sized = |m: &str| m[m.find("steps by ").unwrap()..m.find(" at t =").unwrap()].to_string();
    assert_eq!(
        sized(&p1.findings[0].message),
        sized(&p60.findings[0].message)
    );
    assert!(
        p1.findings[0]
            .message
            .contains("the 60-s window holding the jump left out"),
        "{}",
        p1.findings[0].message
    );
}

#[test]
fn a_bias_step_of_four_times_the_noise_of_a_mean_is_found_and_repaired() {
    // 4e-4 m/s² (4× the 1σ of a 60-s mean; 10σ of the ±6-h fit that sizes it): the local
    // level-shift scan alone (1σ ~1.3e-4) found no step of this size in 20 of 20 seeds, and
    // the run then misfit. Now found, sized within 3σ of the truth, the estimate trusted.
    let (sc, samples) = run_with_faults(5, 60.0, &["step=y,4e-4,30"]);
    let prep = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
    assert_eq!(kinds(&prep), ["acc-bias-step"], "{:#?}", prep.findings);
    let m = &prep.findings[0].message;
    let i = m.find("steps by ").unwrap() + 9;
    let rest: Vec<&str> = m[i..].split_whitespace().collect();
    let (size, sd) = (
        rest[0].parse::<f64>().unwrap(),
        rest[2].parse::<f64>().unwrap(),
    );
    assert!((size - 4e-4).abs() < 3.0 * sd, "size {size} ± {sd}");
    let worst = worst_err_over_sigma(&sc, &prep);
    assert!(worst < 3.0, "worst |error|/σ {worst:.2}");
}

#[test]
fn a_gauss_markov_drift_is_not_taken_for_bias_steps() {
    // A Gauss–Markov drift wanders the platform slowly; the bias-step scan's ±6-h fit does not
    // follow that and found 3 "steps" per axis on every axis (seeds 1–3 of σ 0.01 deg/h, τ 5 h)
    // and repaired them: a physical effect taken for a data fault. Several candidates in a run
    // are now slow structure left to the model ladder (which names drift-markov): no finding.
    let mut sc = Scenario::paper();
    sc.seed = 1;
    sc.effects = vec!["drift-markov=0.01,0.01,0.01:5,5,5".parse().unwrap()];
    let sim = simulate(&sc);
    let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
    let prep = prepare(site_of(&sc), &samples, &Config::default()).unwrap();
    assert!(prep.findings.is_empty(), "{:#?}", prep.findings);
}
