//! Recordings in the shape of outside data: a random site, length, sampling, start, set-up errors
//! drawn from the priors, and none, one or two of a dozen effects, most of them outside the catalog
//! (a gyro turn-on transient, a periodic drift of any period, a Markov wander, a clock running
//! fast, a tilting vertical, a start off north).
//! `identify` and `diagnose` may say "not trusted" (exit 3) as often as they must, but an exit 0
//! must never come with a drift coefficient far outside its total 1σ.
//!
//! Tolerance: 4 total σ. A trusted run's 12 coefficients, if their 1σ is honest, all lie within
//! 4σ with probability 99.9 %; over this test's 4–10 trusted answers a false failure is ≤ 1 % likely.
//! The confident wrong answers that random recordings found (and that are fixed) were 4.3–11σ.
//! The scenarios are drawn from a fixed seed: the test is deterministic.

use rand::seq::IndexedRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};
use std::process::Command;

fn driftid() -> Command {
    Command::new(env!("CARGO_BIN_EXE_driftid"))
}

/// One random scenario's `simulate` arguments.
fn scenario(rng: &mut ChaCha8Rng, seed: u64) -> Vec<String> {
    let mut a: Vec<String> = vec![
        "--seed".into(),
        seed.to_string(),
        "--hours".into(),
        [24, 36][rng.random_range(0..2)].to_string(),
        "--rate-s".into(),
        [10, 30][rng.random_range(0..2)].to_string(),
        format!(
            "--latitude-deg={}",
            ["39.1", "45.52", "-30.3", "60.25", "21.7", "-42.88", "51.5"]
                .choose(rng)
                .unwrap()
        ),
    ];
    if rng.random_bool(0.7) {
        a.push("--setup-errors-from-priors".into());
    }
    if rng.random_bool(0.3) {
        a.push("--initial-orientation-deg".into());
        a.push(format!(
            "{},{},{}",
            [0, 30, 90, 180].choose(rng).unwrap(),
            [0, 20, 45].choose(rng).unwrap(),
            [0, 90, 135].choose(rng).unwrap()
        ));
    }
    let v3 = |rng: &mut ChaCha8Rng, size: f64| {
        (0..3)
            .map(|_| {
                let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                format!("{:.3e}", sign * size * rng.random_range(0.5..1.5))
            })
            .collect::<Vec<_>>()
            .join(",")
    };
    let kinds = [
        "acc-bias",
        "acc-scale",
        "drift-sine",
        "drift-transient",
        "temp-drift",
        "drift-markov",
        "acc-temp",
        "clock",
        "vtilt",
        "az",
        "g2",
        "trend",
    ];
    let count = rng.random_range(0..=2);
    let mut temp = false;
    for kind in kinds
        .choose_multiple(rng, count)
        .copied()
        .collect::<Vec<_>>()
    {
        let effect = match kind {
            "acc-bias" => format!("acc-bias={}", v3(rng, 1e-4)),
            "acc-scale" => format!("acc-scale={}", v3(rng, 50.0)),
            "drift-sine" => format!(
                "drift-sine={}:{}",
                v3(rng, 7e-4),
                [12, 24, 30].choose(rng).unwrap()
            ),
            "drift-transient" => format!(
                "drift-transient={}:{}",
                v3(rng, 4e-3),
                [2, 3, 5].choose(rng).unwrap()
            ),
            "temp-drift" => {
                temp = true;
                format!("temp-drift={}", v3(rng, 2e-3))
            }
            "drift-markov" => format!(
                "drift-markov={}:10,10,10",
                (0..3)
                    .map(|_| format!("{:.3e}", 1e-3 * rng.random_range(0.5..1.5)))
                    .collect::<Vec<_>>()
                    .join(",")
            ),
            "acc-temp" => {
                temp = true;
                format!("acc-temp={}", v3(rng, 3e-5))
            }
            "g2" => format!(
                "g2={}",
                (0..18)
                    .map(|_| format!("{:.2e}", rng.random_range(-3e-5..3e-5)))
                    .collect::<Vec<_>>()
                    .join(",")
            ),
            "trend" => format!("drift-trend={}", v3(rng, 5e-6)),
            "clock" => {
                let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                a.push(format!(
                    "--clock-error-ppm={}",
                    sign * rng.random_range(50.0..400.0)
                ));
                continue;
            }
            "vtilt" => {
                a.push(format!(
                    "--vertical-tilt-arcsec={},{}",
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-3.0..3.0)
                ));
                continue;
            }
            _ => {
                a.push(format!(
                    "--start-error-arcsec=0,0,{}",
                    rng.random_range(-40.0..40.0)
                ));
                continue;
            }
        };
        a.push("--effect".into());
        a.push(effect);
    }
    if temp {
        a.push("--write-temp".into());
    }
    a
}

/// `driftid simulate ARGS --out csv`, which must succeed.
fn simulate(args: &[String], csv: &Path) {
    let sim = driftid()
        .arg("simulate")
        .args(args)
        .arg("--out")
        .arg(csv)
        .output()
        .unwrap();
    assert!(
        sim.status.success(),
        "simulate {args:?}: {}",
        String::from_utf8_lossy(&sim.stderr)
    );
}

/// `driftid COMMAND csv --truth … --json`: exit code and the largest |error| / total 1σ of the
/// paper's 12 drift coefficients.
fn worst(command: &str, csv: &Path, args: &[String]) -> (Option<i32>, f64, String) {
    let out = driftid()
        .arg(command)
        .arg(csv)
        .arg("--truth")
        .arg(csv.with_extension("truth.json"))
        .arg("--json")
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|_| panic!("{command} {args:?}: no JSON: {text}"));
    let z = v["coefficients"]
        .as_object()
        .unwrap()
        .iter()
        .filter(|(n, _)| n.starts_with('D') && n.len() == 3)
        .map(|(_, c)| (c["error"].as_f64().unwrap() / c["sigma_total"].as_f64().unwrap()).abs())
        .fold(0.0, f64::max);
    (out.status.code(), z, text)
}

#[test]
fn outside_like_recordings_are_never_trusted_far_off() {
    let dir: PathBuf = std::env::temp_dir().join(format!("driftid-outside-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(26);
    let mut trusted = 0;
    for k in 0..12u64 {
        let args = scenario(&mut rng, 7000 + k);
        let csv = dir.join(format!("run{k}.csv"));
        simulate(&args, &csv);
        for command in ["identify", "diagnose"] {
            let (code, z, text) = worst(command, &csv, &args);
            assert!(matches!(code, Some(0 | 3)), "{command} {args:?}: {text}");
            if code == Some(0) {
                trusted += 1;
                assert!(
                    z <= 4.0,
                    "{command} {args:?}: trusted with a drift coefficient {z:.2} total σ off"
                );
            }
            eprintln!("{command} exit {code:?}, worst {z:.2}σ: {args:?}");
        }
    }
    // The test means something only if some answers are trusted.
    assert!(trusted >= 4, "only {trusted} of 24 answers trusted");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Found by the random recordings above (seed 9207 of the sweep's generator): a start that fits,
/// a score test naming `drift-daily`, and a 30-h periodic drift underneath (36 h at 10 s, the
/// set-up drawn from the priors). The ladder added `drift-daily` unopposed and `diagnose` trusted
/// DY0 4.1 total σ off; the profiled candidates now compete whenever an effect is to be added.
#[test]
fn a_periodic_drift_under_a_fitting_start_is_not_trusted_as_a_daily_drift() {
    not_confidently_wrong(
        "periodic",
        &[
            "--seed",
            "9207",
            "--hours",
            "36",
            "--rate-s",
            "10",
            "--latitude-deg=-42.88",
            "--setup-errors-from-priors",
            "--initial-orientation-deg",
            "90,20,135",
            "--effect",
            "drift-sine=8.101e-04,-5.328e-04,-7.197e-04:30",
        ],
    );
}

/// Found by the random recordings above (seed 9307): a Gauss–Markov wander of ~1e-3 deg/h (τ
/// 10 h; 36 h at 10 s, the set-up drawn from the priors, a clock 96 ppm slow). Weighed at the
/// catalog's σ = 0.01 deg/h, `drift-markov` lost to `g2` by 238; `g2` and a drift step were
/// adopted and `diagnose` trusted DYx 9.9 total σ off. It is now weighed at the σ and τ the data
/// prefer too.
#[test]
fn a_small_wander_is_not_trusted_as_g2_and_a_drift_step() {
    not_confidently_wrong(
        "wander",
        &[
            "--seed",
            "9307",
            "--hours",
            "36",
            "--rate-s",
            "10",
            "--latitude-deg=39.1",
            "--setup-errors-from-priors",
            "--initial-orientation-deg",
            "30,20,90",
            "--clock-error-ppm=-95.73479580751263",
            "--effect",
            "drift-markov=8.227e-04,1.037e-03,1.178e-03:10,10,10",
        ],
    );
}

/// Found by the random recordings above (seed 9509): a wander of ~7e-4 deg/h (τ 10 h; 36 h at
/// 10 s, latitude 60.25°, a clock 347 ppm slow). The ladder added a drift step, then
/// `drift-markov`; tuning its σ and τ, the profile of a flat ridge asked for τ ~ e^-40 h and the
/// propagation's sub-steps (8 per τ) never ended: `diagnose` ran for hours. It now keeps to the
/// range searched (unit test `the_profile_stays_in_the_range_searched_on_a_flat_ridge`) and
/// ends in seconds (3 s on a 2-core machine).
#[test]
fn a_wander_after_a_drift_step_is_tuned_in_seconds() {
    not_confidently_wrong(
        "wander-step",
        &[
            "--seed",
            "9509",
            "--hours",
            "36",
            "--rate-s",
            "10",
            "--latitude-deg=60.25",
            "--clock-error-ppm=-347.2370854956184",
            "--effect",
            "drift-markov=5.529e-04,5.634e-04,1.059e-03:10,10,10",
        ],
    );
}

/// Found by the random recordings above (seed 9690): a wander of ~8e-4 deg/h (τ 10 h; 36 h at
/// 30 s, latitude 21.7°, the set-up drawn from the priors). The data preferred `drift-markov` to
/// `g2` by 56, but a rung takes a deterministic law that explains the data to the noise floor,
/// and the final model was never weighed against the catch-all in the law's place: trusted with
/// DX0 3.8 total σ off. It is now (`ladder::overruled`): exit 3, the two named.
#[test]
fn a_wander_the_ladder_took_for_g2_is_weighed_in_its_place() {
    not_confidently_wrong(
        "wander-g2",
        &[
            "--seed",
            "9690",
            "--hours",
            "36",
            "--rate-s",
            "30",
            "--latitude-deg=21.7",
            "--setup-errors-from-priors",
            "--effect",
            "drift-markov=6.306e-04,7.963e-04,8.726e-04:10,10,10",
        ],
    );
}

/// Found by the random recordings above (seed 9793): a wander of ~1e-3 deg/h (τ 10 h; 36 h at
/// 10 s, latitude 45.52°). The ladder took `g2` over `drift-markov` (640.0 against 701.9), then a
/// drift step over it (22.2 against 37.3). A drift step is a candidate made for the run, with no
/// refit in the catalog's ranking, so the ladder's additions were weighed against nothing and
/// `diagnose` trusted a coefficient 5.1 total σ off. Now exit 3: the data prefer `drift-markov`
/// instead of `g2 + drift-step`.
#[test]
fn a_wander_taken_for_g2_and_a_drift_step_is_weighed_in_their_place() {
    not_confidently_wrong(
        "wander-g2-step",
        &[
            "--seed",
            "9793",
            "--hours",
            "36",
            "--rate-s",
            "10",
            "--latitude-deg=45.52",
            "--effect",
            "drift-markov=5.280e-04,1.366e-03,5.626e-04:10,10,10",
        ],
    );
}

/// Found by a sweep of two hidden effects (session 39's q1_2): a misaligned accelerometer triad,
/// a 39.7-h periodic drift and a clock 100 ppm fast, 60 h at 5 s at 53.2° S. The ladder's four
/// models (acc-bias, acc-scale, drift-markov) were used up with `acc-misalign` still gaining
/// 159.5: exit 3 with the advice "run `driftid diagnose`" — the command just run. With room for
/// eight models the ladder adds it and stops by itself; the run is trusted (every drift
/// coefficient within 1.51 total σ measured, 3 asserted). Of 100 such recordings the cap had
/// cut two short; the other 33 that reached four models stopped there by themselves.
#[test]
fn a_ladder_is_not_cut_short_while_an_effect_still_earns_its_place() {
    let args = [
        "--seed",
        "362493",
        "--hours",
        "60",
        "--rate-s",
        "5",
        "--latitude-deg=-53.185",
        "--setup-errors-from-priors",
        "--clock-error-ppm",
        "-100",
        "--effect",
        "acc-misalign=-1.6e-05,-1.7e-05,-2.4e-06,-1.3e-05,-2.9e-05,2.0e-05",
        "--effect",
        "drift-sine=1.13e-04,2.85e-04,-6.28e-04:39.7",
    ];
    let text = not_confidently_wrong("ladder-cap", &args);
    assert!(
        text.contains("acc-misalign") && !text.contains("run `driftid diagnose`"),
        "{text}"
    );
}

/// Found by a sweep of misstated latitudes under an uncatalogued wander (session 41's n4_4): a
/// 5.7-h sine drift, 48 h at 5 s at 41.58° N written as 41.48. `diagnose` added `drift-markov`,
/// whose σ and τ, tuned at the stated latitude, stretched (τ 19 h against 1.0 h at the true one)
/// to absorb the latitude's signature; the misstated latitude, refitted with that wander held,
/// lost by 11.6 and the run was trusted with DXx 29 total σ off. Each misstatement is now weighed
/// with its own wander (`markov::retuned_refit`): exit 3, the latitude named.
#[test]
fn a_misstated_latitude_under_a_wander_is_weighed_with_its_own_wander() {
    not_confidently_wrong(
        "latitude-wander",
        &[
            "--seed",
            "852064",
            "--hours",
            "48",
            "--rate-s",
            "5",
            "--latitude-deg=41.480",
            "--latitude-error-deg=-0.100",
            "--effect",
            "drift-sine=1.98e-04,-1.38e-04,-6.77e-04:5.7",
        ],
    );
}

/// `diagnose` of the recording `args` simulate: deterministic (fixed seed), it must end in
/// exit 3 or with every drift coefficient within 3 total σ of the truth.
fn not_confidently_wrong(tag: &str, args: &[&str]) -> String {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("driftid-outside-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("run.csv");
    let args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
    simulate(&args, &csv);
    let (code, z, text) = worst("diagnose", &csv, &args);
    assert!(
        code == Some(3) || (code == Some(0) && z <= 3.0),
        "exit {code:?}, worst {z:.2} total σ: {text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    text
}

/// Found by the sweep's random recordings (seed 9567): a hidden accelerometer bias, 36 h at
/// 10 s at 30.3° S. The paper's single EKF pass lost positive definiteness at update 1855 and
/// `identify` and `diagnose` ended in exit 2 ("single EKF pass: … not positive definite"): no
/// answer at all, and inside `diagnose` such a refit dropped a rival silently (seed 9207 above).
/// The smoother now fits by continuation without that pass: an answer, the single-pass columns
/// "—" (JSON `null`), and `diagnose` not confidently wrong.
#[test]
fn a_diverged_single_pass_still_gives_an_answer() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("driftid-outside-diverged-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("run.csv");
    let args: Vec<String> = [
        "--seed",
        "9567",
        "--hours",
        "36",
        "--rate-s",
        "10",
        "--latitude-deg=-30.3",
        "--effect",
        "acc-bias=1.106e-04,5.986e-05,9.969e-05",
    ]
    .iter()
    .map(|a| a.to_string())
    .collect();
    simulate(&args, &csv);
    let out = driftid()
        .args(["identify", "--json"])
        .arg(&csv)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(matches!(out.status.code(), Some(0 | 3)), "{text}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(
        v["coefficients"]["DX0"]["single_pass"].is_null(),
        "the single pass diverges on this recording: {}",
        v["coefficients"]["DX0"]
    );
    assert!(v["coefficients"]["DX0"]["value"].is_f64());
    let (code, z, text) = worst("diagnose", &csv, &args);
    assert!(
        code == Some(3) || (code == Some(0) && z <= 3.0),
        "exit {code:?}, worst {z:.2} total σ: {text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
