//! The `driftid` binary as a user runs it: simulate → identify --json, and bad recordings.

use std::path::PathBuf;
use std::process::Command;

fn driftid() -> Command {
    Command::new(env!("CARGO_BIN_EXE_driftid"))
}

/// A fresh directory for one test, removed with what is in it when the test ends, passed or
/// failed (the suite left ~10 MB of recordings in the temp directory on every run).
fn temp_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("driftid-cli-{name}-"))
        .tempdir()
        .unwrap()
}

#[test]
fn simulate_then_identify_json_has_the_documented_fields() {
    let tmp = temp_dir("json");
    let dir = tmp.path();
    let csv = dir.join("run.csv");
    let out = driftid()
        .args([
            "simulate",
            "--scenario",
            "paper",
            "--hours",
            "36",
            "--rate-s",
            "10",
            "--seed",
            "3",
            "--out",
        ])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "simulate failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = driftid()
        .arg("identify")
        .arg(&csv)
        .arg("--truth")
        .arg(dir.join("run.truth.json"))
        .arg("--json")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "identify failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("one JSON object on stdout");
    let truth = [
        0.5, -0.1, -0.05, -0.05, -0.5, 0.05, 0.1, 0.05, 0.5, -0.05, 0.05, -0.1,
    ];
    for (k, name) in [
        "DX0", "DXx", "DXy", "DXz", "DY0", "DYx", "DYy", "DYz", "DZ0", "DZx", "DZy", "DZz",
    ]
    .iter()
    .enumerate()
    {
        let c = &v["coefficients"][name];
        let (value, noise, sigma) = (
            c["value"].as_f64().unwrap(),
            c["sigma"].as_f64().unwrap(),
            c["sigma_total"].as_f64().unwrap(),
        );
        // 36 h is past one sidereal day: the converged estimate is consistent, and its total 1σ
        // carries the set-up's priors (the latitude is estimated from the data, which
        // determine it to ~0.006° here), so 4 total σ (a two-sided 6e-5 chance per coefficient)
        // only fails on a real regression. The total never claims more than the noise alone.
        assert!(
            noise > 0.0 && sigma >= noise && (value - truth[k]).abs() < 4.0 * sigma,
            "{name}: {value} ± {sigma} (noise only {noise})"
        );
    }
    assert!((v["final_time_h"].as_f64().unwrap() - 36.0).abs() < 0.02);
    let rms = v["residual_rms_mps2"].as_array().unwrap();
    assert_eq!(rms.len(), 3);
    // Residual RMS against the 60-s noise floor 1e-5 g = 9.8e-5 m/s² (6 samples of 10 s per window
    // keep the same floor: the simulator scales raw noise with sqrt(60/rate)).
    for r in rms {
        let r = r.as_f64().unwrap();
        assert!(r > 0.8 * 9.8e-5 && r < 1.1 * 9.8e-5, "residual RMS {r}");
    }
    assert!((v["nis_mean"].as_f64().unwrap() - 1.0).abs() < 0.15);
    // `diagnose --truth` (issue 29: diagnose had none): the final model's coefficients carry the
    // truth and the error, the same 4-total-σ bound holds; with two recordings it is refused.
    let truth_file = dir.join("run.truth.json");
    let out = driftid()
        .arg("diagnose")
        .arg(&csv)
        .arg("--truth")
        .arg(&truth_file)
        .arg("--json")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let d: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for (name, k) in ["DX0", "DYx", "DZz"].into_iter().zip([0, 5, 11]) {
        let c = &d["coefficients"][name];
        let (value, error, sigma) = (
            c["value"].as_f64().unwrap(),
            c["error"].as_f64().unwrap(),
            c["sigma_total"].as_f64().unwrap(),
        );
        assert!((error - (value - truth[k])).abs() <= 1e-12 * value.abs().max(1.0));
        assert!(
            error.abs() < 4.0 * sigma,
            "{name}: error {error} vs 1σ {sigma}"
        );
    }
    let out = driftid()
        .arg("diagnose")
        .arg(&csv)
        .arg(&csv)
        .arg("--truth")
        .arg(&truth_file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--truth takes one recording"));
}

#[test]
fn a_broken_recording_is_a_located_error_not_a_panic() {
    let tmp = temp_dir("broken");
    let dir = tmp.path();
    let cases: [(&str, &str, &[&str]); 5] = [
        (
            "missing.csv",
            "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2\n0,0,0\n",
            &["missing.csv", "az_mps2"],
        ),
        (
            "badnum.csv",
            "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n1,0,abc,9.8\n",
            &["badnum.csv:4", "ay_mps2"],
        ),
        (
            "time.csv",
            "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n1,0,0,9.8\n1,0,0,9.8\n",
            &["time.csv:5"],
        ),
        (
            "nan.csv",
            // A NaN sample is rejected and counted by the screening; two samples are too few.
            "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n1,NaN,0,9.8\n",
            &["nan.csv", "too-few-samples"],
        ),
        ("empty.csv", "", &["empty.csv"]),
    ];
    for (name, text, needles) in cases {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        let out = driftid().arg("identify").arg(&path).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        // 2: an input that cannot be used (README, "Bad input").
        assert_eq!(
            out.status.code(),
            Some(2),
            "{name}: exit code; stderr: {stderr}"
        );
        assert!(!stderr.contains("panicked"), "{name}: panic: {stderr}");
        for n in needles {
            assert!(
                stderr.contains(n),
                "{name}: error should mention `{n}`: {stderr}"
            );
        }
    }
}

#[test]
fn demo_runs_without_arguments() {
    let out = driftid().arg("demo").output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = String::from_utf8_lossy(&out.stdout);
    assert!(s.contains("paper T2") && s.contains("DZz") && s.contains("converged"));
    // Issue 29 item 11: g² widens D0's 1σ some 60×; the ladder points to `plan`, which can
    // separate it with a second orientation. The ladder adds g2 alone: with g2's prior at 1e-4
    // deg/h/(m/s²)² the demo's g² drift (5e-4) was shrunk and a spurious `drift-daily` joined it.
    assert!(
        s.contains("the added effects widen a 1σ up to ×")
            && s.contains("`driftid plan RUN.csv --with g2` says which"),
        "{s}"
    );
}

/// `driftid report` on a run with a hidden accelerometer bias: one self-contained HTML page that
/// tells the story (the paper model fails, acc-bias is named, the ladder adds it and the residual
/// falls to the floor), plus the PNG of every plot.
#[test]
fn report_is_one_self_contained_page_that_tells_the_story() {
    let tmp = temp_dir("report");
    let dir = tmp.path();
    let csv = dir.join("run.csv");
    let out = driftid()
        .args([
            "simulate",
            "--hours",
            "48",
            "--rate-s",
            "10",
            "--seed",
            "5",
            "--effect",
            "acc-bias=2e-4,-1e-4,0",
            "--out",
        ])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "simulate failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let html = dir.join("report.html");
    let png = dir.join("png");
    let out = driftid()
        .arg("report")
        .arg(&csv)
        .arg("--truth")
        .arg(dir.join("run.truth.json"))
        .arg("-o")
        .arg(&html)
        .arg("--png")
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "report failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let page = std::fs::read_to_string(&html).unwrap();
    // Trusted: the verdict block says on what (the alternatives the coefficients hold only on
    // the absence of, or none), before the story's first section.
    let verdict = &page[page.find("<section id=\"verdict\"").unwrap()..];
    let verdict = &verdict[..verdict.find("</section>").unwrap()];
    assert!(
        verdict.contains("Trusted on the absence of what this run cannot rule out")
            || verdict.contains("No alternative this run cannot rule out"),
        "{verdict}"
    );
    // Self-contained: the only URL is the SVG namespace; no script, stylesheet or image fetched.
    let urls: Vec<&str> = page
        .match_indices("http")
        .map(|(i, _)| &page[i..(i + 30).min(page.len())])
        .collect();
    assert!(
        urls.iter()
            .all(|u| u.starts_with("http://www.w3.org/2000/svg")),
        "external references: {urls:?}"
    );
    for banned in ["<script", "<link", "<img", "@import", "url("] {
        assert!(
            !page.contains(banned),
            "the page must not load anything ({banned})"
        );
    }
    // Every plot inline (11 figures when the ladder has a second rung), every section present.
    assert_eq!(page.matches("<svg").count(), 11, "inline SVG plots");
    for section in [
        "1. The model against the measurements",
        "2. Where it fails",
        "3. Which physical effect is missing",
        "4. Add it and watch the error fall",
        "5. Identified coefficients",
    ] {
        assert!(page.contains(section), "missing section {section}");
    }
    // Provenance (issue 29): the command that made the page, with its version.
    assert!(
        page.contains("How this page was made")
            && page.contains("report ")
            && page.contains(env!("CARGO_PKG_VERSION")),
        "no provenance"
    );
    // The story: the starting model is paper, the ladder's next rung adds acc-bias.
    assert!(
        page.contains("<b>acc-bias</b>"),
        "acc-bias ranked in the table"
    );
    assert!(
        page.contains("Final model (paper + acc-bias)"),
        "the ladder climbs to paper + acc-bias"
    );
    for name in ["DX0", "DZz", "BAx", "BAz"] {
        assert!(
            page.contains(&format!(">{name}<")),
            "coefficient {name} in the final table"
        );
    }
    // Text, not markup, where a p-value is tiny: "< 1e-300" must be escaped.
    assert!(!page.contains("< 1e-300"));
    page_structure(&page);
    // PNGs: one valid file per figure.
    let mut files: Vec<_> = std::fs::read_dir(&png)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert_eq!(files.len(), 11);
    for f in &files {
        let bytes = std::fs::read(f).unwrap();
        assert!(
            bytes.starts_with(b"\x89PNG\r\n\x1a\n") && bytes.len() > 10_000,
            "{} is not a drawn PNG",
            f.display()
        );
    }
}

/// `driftid simulate ARGS --out DIR/NAME`, which must succeed: the recording's path.
fn simulate_to(dir: &std::path::Path, name: &str, args: &[&str]) -> PathBuf {
    let csv = dir.join(name);
    let out = driftid()
        .arg("simulate")
        .args(args)
        .arg("--out")
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "simulate {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    csv
}

fn simulate_run(
    dir: &std::path::Path,
    name: &str,
    seed: &str,
    orientation: &str,
    extra: &[&str],
) -> PathBuf {
    let mut args = vec!["--hours", "36", "--rate-s", "30", "--seed", seed];
    args.extend(["--initial-orientation-deg", orientation]);
    args.extend(extra);
    simulate_to(dir, name, &args)
}

#[test]
fn several_runs_are_identified_diagnosed_and_planned_together() {
    // Two runs of one system (an accelerometer bias on top of the paper's drift), level and at
    // (90°, 0°, 90°): diagnose names acc-bias on each and identifies it jointly; identify and plan
    // accept the same runs; every result within 3 of its total 1σ (the joint estimate has each
    // run's set-up marginalised, so its error is judged against the total: it was 0.02–2 of the
    // noise-only 1σ when the stated set-up was taken as exact, and DZz is 7 of it now).
    let tmp = temp_dir("joint");
    let dir = tmp.path();
    let bias = ["--effect", "acc-bias=2e-4,-1e-4,3e-4"];
    let a = simulate_run(dir, "a.csv", "21", "0,0,0", &bias);
    let b = simulate_run(dir, "b.csv", "22", "90,0,90", &bias);
    let out = driftid()
        .arg("diagnose")
        .args([&a, &b])
        .arg("--json")
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["joint_model"], serde_json::json!(["acc-bias"]), "{v}");
    let coefs = &v["joint"]["coefficients"];
    for (name, truth) in [
        ("BAx", 2e-4),
        ("BAy", -1e-4),
        ("BAz", 3e-4),
        ("DX0", 0.5),
        ("DZz", -0.1),
    ] {
        let c = &coefs[name];
        let z = (c["value"].as_f64().unwrap() - truth) / c["sigma_total"].as_f64().unwrap();
        assert!(z.abs() < 3.0, "{name}: {z:.2}σ");
    }
    assert_eq!(v["joint"]["runs"].as_array().unwrap().len(), 2);
    let out = driftid()
        .arg("identify")
        .args([&a, &b])
        .args(["--with", "acc-bias", "--json", "--truth"])
        .arg(dir.join("a.truth.json"))
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["coefficients"]["BAz"]["truth"], serde_json::json!(3e-4));
    let out = driftid()
        .arg("plan")
        .arg(&a)
        .args(["--with", "acc-bias", "--json"])
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // The plan's next run must shrink the weakest combination's 1σ (one level run: 12–19×
    // weaker than the next direction; any second orientation in the grid helps several-fold):
    // the noise-only one by ≥ 3× (measured 29×); the total, which keeps the first run's set-up
    // share (a second run's own set-up is independent of it), by ≥ 2× (measured 2.7×).
    let score = |key: &str| v[key].as_f64().unwrap();
    let (now, after) = (score("score_before"), score("score_after"));
    let (now_noise, after_noise) = (
        score("score_before_noise_only"),
        score("score_after_noise_only"),
    );
    assert!(
        after_noise < now_noise / 3.0,
        "{now_noise} -> {after_noise}"
    );
    assert!(after < now / 2.0, "{now} -> {after}");
}

/// A recording whose metadata latitude is wrong (45° for a run at 39.1°, with no gravity line,
/// so gravity follows the stated latitude): every command that fits a model names the metadata
/// as the fault. On one run it exits 3 (numbers computed, not trusted); a joint fit or a plan
/// with that run refuses it, exit 2 (the runs cannot be fitted together on a wrong site).
/// `report` once said "no finding", explained the misfit by an accelerometer scale factor and
/// exited 0, and `plan` planned the next run from it, exit 0; a joint fit failed with "innovation
/// covariance not positive definite" — all from the same data `diagnose` got right.
#[test]
fn a_wrong_latitude_is_named_by_every_command() {
    let tmp = temp_dir("wrong-latitude");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &["--hours", "10", "--rate-s", "10", "--seed", "2"],
    );
    // The wrong-latitude run is another run (seed 3): the same samples as run.csv would be
    // refused as the same data twice by the joint fit (issue 28), before the latitude.
    let other = simulate_to(
        dir,
        "other.csv",
        &["--hours", "10", "--rate-s", "10", "--seed", "3"],
    );
    let text = std::fs::read_to_string(&other).unwrap();
    let wrong: String = text
        .lines()
        .filter(|l| !l.starts_with("# gravity_mps2"))
        .map(|l| {
            if l.starts_with("# latitude_deg") {
                "# latitude_deg: 45.0\n".to_string()
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    let bad = dir.join("wrong.csv");
    std::fs::write(&bad, &wrong).unwrap();
    let html = dir.join("wrong.html");
    let runs: [(&str, Vec<std::ffi::OsString>, i32); 5] = [
        ("identify", vec!["identify".into(), bad.clone().into()], 3),
        ("diagnose", vec!["diagnose".into(), bad.clone().into()], 3),
        (
            "report",
            vec![
                "report".into(),
                bad.clone().into(),
                "-o".into(),
                html.clone().into(),
            ],
            3,
        ),
        (
            "identify, two runs",
            vec!["identify".into(), csv.clone().into(), bad.clone().into()],
            2,
        ),
        ("plan", vec!["plan".into(), bad.clone().into()], 2),
    ];
    for (name, args, code) in runs {
        let out = driftid().args(&args).output().unwrap();
        let all = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(
            out.status.code(),
            Some(code),
            "{name}: exit {code} expected:\n{all}"
        );
        assert!(
            all.contains("the data put the site at latitude 39.1"),
            "{name}: the latitude named:\n{all}"
        );
    }
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(
        page.contains("the data put the site at latitude 39.1"),
        "the page names it"
    );
    // The input is untouched.
    assert_eq!(std::fs::read_to_string(&bad).unwrap(), wrong);
}

/// `plan` from a run its model does not explain (an accelerometer bias the paper's model lacks)
/// says so and exits 3: its "1σ now" and the information behind the recommended orientation come
/// from that fit. It once exited 0. With the missing effect in the model the plan is trusted.
#[test]
fn a_plan_from_a_run_the_model_does_not_explain_is_not_trusted() {
    let tmp = temp_dir("plan-misfit");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--hours",
            "12",
            "--rate-s",
            "10",
            "--seed",
            "4",
            "--effect",
            "acc-bias=4e-4,-3e-4,2e-4",
        ],
    );
    for (with, code) in [(None, 3), (Some("acc-bias"), 0)] {
        let mut cmd = driftid();
        cmd.arg("plan").arg(&csv);
        if let Some(w) = with {
            cmd.args(["--with", w]);
        }
        let out = cmd.output().unwrap();
        let all = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(out.status.code(), Some(code), "--with {with:?}:\n{all}");
        assert!(all.contains("plan: next run"), "a plan is printed:\n{all}");
        assert_eq!(
            all.contains("does not explain this run"),
            code == 3,
            "--with {with:?}: the misfit named exactly when it is there:\n{all}"
        );
        // Issue 29 item 11: a ready `driftid simulate` line for the planned run, which runs
        // (its output put in the test's folder) and makes a recording of that orientation.
        let line = all
            .lines()
            .find_map(|l| l.split_once("to try it in simulation: driftid "))
            .map(|(_, rest)| rest.to_string())
            .unwrap_or_else(|| panic!("no simulate line:\n{all}"));
        let mut args: Vec<std::ffi::OsString> = line.split_whitespace().map(Into::into).collect();
        let out_at = args.iter().position(|a| a == "--out").unwrap() + 1;
        args[out_at] = dir.join(format!("next-{}.csv", with.is_some())).into();
        let (status, text) = run_driftid(&args);
        assert_eq!(status, Some(0), "{line}:\n{text}");
        assert!(dir.join(format!("next-{}.csv", with.is_some())).is_file());
    }
}

/// Runs driftid and returns (exit code, stdout + stderr).
fn run_driftid(args: &[std::ffi::OsString]) -> (Option<i32>, String) {
    let out = driftid().args(args).output().unwrap();
    let all = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.code(), all)
}

/// Issue 27 item 6: a step the tool cannot repair (here 5e-3 m/s² on y at 7.9 h of an 8-h run:
/// too near the end to be sized on hours of means, so a `step`, not an `acc-bias-step`) makes
/// identify exit 3 and its message suggests `--exclude`; the user, who knows the run went bad
/// at 7.9 h, leaves 7.85..8 h out: identify, diagnose and report then report the window as an
/// `excluded` finding with its range and exit 0 (before: no such option, exit 2).
#[test]
fn a_window_is_excluded_by_every_command_and_an_unrepaired_step_suggests_it() {
    let tmp = temp_dir("exclude");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &["--hours", "8", "--seed", "3", "--fault", "step=y,5e-3,7.9"],
    );
    let (code, all) = run_driftid(&["identify".into(), csv.clone().into()]);
    assert_eq!(code, Some(3), "{all}");
    assert!(
        all.contains("step") && all.contains("--exclude 7.8"),
        "the step suggests --exclude from about where it begins:\n{all}"
    );
    let html = dir.join("run.html");
    let with = |cmd: &str| -> Vec<std::ffi::OsString> {
        let mut v: Vec<std::ffi::OsString> = vec![cmd.into(), csv.clone().into()];
        v.extend(["--exclude".into(), "7.85..8".into()]);
        if cmd == "report" {
            v.extend(["-o".into(), html.clone().into()]);
        }
        v
    };
    for cmd in ["identify", "diagnose", "report"] {
        let (code, all) = run_driftid(&with(cmd));
        assert_eq!(code, Some(0), "{cmd} --exclude 7.85..8:\n{all}");
        assert!(
            all.contains("excluded") && all.contains("7.8500–8.0000 h"),
            "{cmd}: the window named with its range:\n{all}"
        );
    }
    assert!(std::fs::read_to_string(&html)
        .unwrap()
        .contains("7.8500–8.0000 h"));
    // The JSON finding: kind, range in seconds, samples left out (t = 28 260 … 28 800 s at 1 s).
    let mut args = with("identify");
    args.push("--json".into());
    let out = driftid().args(&args).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let f = v["data_quality"]["findings"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["kind"] == "excluded")
        .expect("an excluded finding");
    assert_eq!(f["start_s"], 28260.0);
    assert_eq!(f["end_s"], 28800.0);
    assert_eq!(f["samples"], 541);
    assert_eq!(f["action"], "rejected");
    // A malformed window is a usage error.
    let (code, _) = run_driftid(&[
        "identify".into(),
        csv.clone().into(),
        "--exclude".into(),
        "8..4".into(),
    ]);
    assert_eq!(code, Some(2));
}

/// Issue 27 item 3 through the CLI: `simulate --fault saturate` makes a recording pinned at
/// ±6.5 m/s² on x (seed 3: x passes 7 m/s² near 5–6 h); identify names it `saturated` with its
/// range and trusts the rest (exit 0; before: steps and a misfit, exit 3). 24 h: on 10 h, less
/// the 3.6 h excluded, a drift trend is a plausible alternative that moves DYx by 1.5 total σ,
/// and the run is rightly not trusted for that.
#[test]
fn a_saturated_recording_from_simulate_is_named_and_trusted() {
    let tmp = temp_dir("saturate");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--hours",
            "24",
            "--seed",
            "3",
            "--fault",
            "saturate=x,6.5,0,10",
        ],
    );
    let (code, all) = run_driftid(&["identify".into(), csv.into()]);
    assert_eq!(code, Some(0), "{all}");
    assert!(
        all.contains("saturated") && all.contains("rail +6.5 m/s^2"),
        "{all}"
    );
}

/// Issue 26 through a joint fit: each run is assessed as `identify` assesses one. A second run
/// recorded with a clock 1000 ppm fast (the data read it as a latitude 0.08° off "39.1", beyond
/// what the written digits allow) makes the joint result untrusted, naming that run alone.
#[test]
fn a_joint_fit_is_not_trusted_when_one_runs_set_up_is_contradicted() {
    let tmp = temp_dir("joint-setup");
    let dir = tmp.path();
    let a = simulate_to(dir, "a.csv", &["--rate-s", "10", "--seed", "1"]);
    let b = simulate_to(
        dir,
        "b.csv",
        &[
            "--rate-s",
            "10",
            "--seed",
            "4",
            "--initial-orientation-deg",
            "135,0,0",
            "--clock-error-ppm",
            "1000",
        ],
    );
    let (code, all) = run_driftid(&["identify".into(), a.into(), b.into()]);
    assert_eq!(code, Some(3), "{all}");
    assert!(all.contains("b.csv alone:"), "{all}");
}

/// Issue 26 through a joint fit: the joint 1σ carries each run's set-up (latitude, clock rate,
/// gravity, the daily tilt and drift), not the fit's alone. Two runs written at "39.1": DXx is
/// limited by the latitude's digits (one run's total is ~30× its noise 1σ; the joint fit's own
/// 1σ is at the noise), so its total must exceed the fit's by far — 5× is a margin below what
/// the latitude alone gives — and no total may be below the fit's.
#[test]
fn a_joint_fits_total_sigma_carries_the_runs_set_up() {
    let tmp = temp_dir("joint-total");
    let dir = tmp.path();
    let a = simulate_to(
        dir,
        "a.csv",
        &["--rate-s", "10", "--hours", "36", "--seed", "2"],
    );
    let b = simulate_to(
        dir,
        "b.csv",
        &[
            "--rate-s",
            "10",
            "--hours",
            "36",
            "--seed",
            "3",
            "--initial-orientation-deg",
            "0,0,90",
        ],
    );
    let out = driftid()
        .arg("identify")
        .args([a.as_os_str(), b.as_os_str()])
        .arg("--json")
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let c = &v["coefficients"];
    for (name, o) in c.as_object().unwrap() {
        let (t, s) = (
            o["sigma_total"].as_f64().unwrap(),
            o["sigma"].as_f64().unwrap(),
        );
        assert!(t >= s, "{name}: total {t} below the fit's {s}");
    }
    let dxx = &c["DXx"];
    let ratio = dxx["sigma_total"].as_f64().unwrap() / dxx["sigma"].as_f64().unwrap();
    assert!(ratio > 5.0, "DXx total / fit 1σ = {ratio:.2}");
}

/// Issue 26 through `diagnose`: a clock 300 ppm fast on a latitude written "39.1" fits within
/// its noise at the start (the data move the latitude within its digits); the ladder then added
/// `drift-daily`, which absorbs the move, and exited 0 with DXx 8σ off. The set-up within its
/// priors is weighed before the ladder as for a misfit: not trusted, the assumed clock named (as
/// `identify` says).
#[test]
fn diagnose_does_not_hide_a_fast_clock_behind_an_effect() {
    let tmp = temp_dir("diagnose-clock");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &["--seed", "11", "--clock-error-ppm", "300"],
    );
    let (code, all) = run_driftid(&["diagnose".into(), csv.into()]);
    assert_eq!(code, Some(3), "{all}");
    assert!(
        all.contains("misstated clock rate") && all.contains("rests on the assumed"),
        "{all}"
    );
}

/// Issue 26: a day's run at 1 s with its set-up drawn from the default priors (gravity a prior σ
/// off, which the data measure to 0.3 ppm: the set-up "moves"). The data know the clock only to
/// ~600 ppm and the latitude to ~0.06°, so a misstated clock or latitude the data cannot rule
/// out would move coefficients beyond their 1σ: with the priors only assumed, such a run is not
/// trusted, and the reason says which prior to state (14 of 20 seeds). Letting a run through
/// when the misstated knob does not "take over" the set-up's move freed 12 of them, but trusted
/// a clock really 337 ppm fast with DZ0 4.4σ off: no data tell those apart, only the user's
/// word. Stated by the user (here the defaults, vouched for), the priors hold: at most 1 of 8
/// distrusted (1 measured, a `drift-daily` the data almost prefer), the trusted within 4 total
/// σ (99.9 % of honest 1σ; measured ≤ 3.4).
#[test]
fn a_day_with_its_set_up_drawn_from_the_priors_rests_on_the_priors_the_user_states() {
    let tmp = temp_dir("setup-priors-day");
    let dir = tmp.path();
    let mut distrusted = vec![];
    for seed in 1..=8 {
        let csv = simulate_to(
            dir,
            &format!("run{seed}.csv"),
            &[
                "--seed",
                &seed.to_string(),
                "--hours",
                "24",
                "--setup-errors-from-priors",
            ],
        );
        let (code, all) = run_driftid(&["identify".into(), csv.clone().into()]);
        assert!(matches!(code, Some(0 | 3)), "seed {seed}: {all}");
        if code == Some(3) && all.contains("rests on the assumed") {
            assert!(all.contains("state what you know of the set-up"), "{all}");
        }
        let out = driftid()
            .arg("identify")
            .arg(&csv)
            .arg("--truth")
            .arg(csv.with_extension("truth.json"))
            .args([
                "--json",
                "--clock-sigma-ppm",
                "20",
                "--gravity-sigma-ppm",
                "30",
            ])
            .args(["--latitude-sigma-deg", "0.029"])
            .output()
            .unwrap();
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        match out.status.code() {
            Some(0) => drift_within_total_sigma(&v, 4.0, &format!("seed {seed}")),
            Some(3) => distrusted.push(format!("seed {seed}: {}", v["untrusted_reasons"])),
            c => panic!("seed {seed}: exit {c:?}"),
        }
    }
    assert!(distrusted.len() <= 1, "{distrusted:#?}");
}

/// A recorder clock 1000 ppm fast on 60 h at 1 s: the data know the clock to ~±300 ppm, so at
/// the default 20-ppm prior no answer is to be trusted. On seed 3 the starting misfit is
/// explained better by the misstated clock than by a drift trend (by 8.3), the ladder added the
/// trend (it absorbs the clock's signature), and the final model, weighed against the clock only
/// on top of the trend, was trusted with DY0 3.3 total σ off: the clock must stay a rival of what
/// the ladder added, and the reason say so. Deterministic (fixed seeds).
#[test]
fn a_clock_misstatement_stays_a_rival_of_what_the_ladder_adds() {
    let tmp = temp_dir("clock-vs-ladder");
    let dir = tmp.path();
    for seed in 1..=3 {
        let csv = simulate_to(
            dir,
            &format!("run{seed}.csv"),
            &["--seed", &seed.to_string(), "--clock-error-ppm", "1000"],
        );
        let (code, all) = run_driftid(&["diagnose".into(), csv.into()]);
        assert_eq!(code, Some(3), "seed {seed}: {all}");
        if seed == 3 {
            // The clock named beside what explains the data as well: the ladder's trend, or a
            // latitude 0.07° off (the latitude's profile fits the data's gravity, so the
            // latitude is not pinned by its normal gravity), a fault that stops the ladder.
            assert!(
                all.contains("a misstated clock rate")
                    && (all.contains("instead of `drift-trend`")
                        || all.contains("wrong metadata latitude from `clock rate misstated`")),
                "{all}"
            );
        }
    }
}

/// The page's structure (issue 29): the verdict as its own block before everything else, a table
/// of contents whose links all land, no table cut at 800 px (each scrolls in a wrapper, numbers
/// never wrap, a base font of at least 14 px), every clipped point marked and counted, long lists
/// openable, Markdown backticks rendered as `<code>`.
fn page_structure(page: &str) {
    // The verdict block: first thing after the title and provenance, trusted and fitting here.
    let verdict = page
        .find("<section id=\"verdict\" class=\"headline trusted\"><p class=\"state\">TRUSTED</p><p class=\"fit\">THE FINAL MODEL FITS</p>")
        .expect("the verdict block");
    assert!(
        verdict < page.find("<h2").unwrap(),
        "the verdict comes first"
    );
    // The table of contents: every link lands on an element of the page.
    let toc = &page[page.find("<nav class=\"toc\">").expect("contents")..];
    let toc = &toc[..toc.find("</nav>").unwrap()];
    let links: Vec<&str> = toc
        .split("href=\"#")
        .skip(1)
        .map(|l| &l[..l.find('"').unwrap()])
        .collect();
    assert!(links.len() >= 8, "contents: {links:?}");
    for id in &links {
        assert!(page.contains(&format!(" id=\"{id}\"")), "no #{id}");
    }
    // No horizontal cut: every table in a scrolling wrapper, numeric cells unbroken, 16 px text.
    let tables = page.matches("<table>").count();
    assert!(tables >= 6);
    assert_eq!(
        page.matches("<div class=\"scroll\"><table>").count(),
        tables
    );
    assert!(page.contains(".scroll{overflow-x:auto"));
    assert!(page.contains("td{white-space:nowrap}"));
    let font = page.split("font-size:").nth(1).unwrap();
    let px: f64 = font[..font.find("px").unwrap()].parse().unwrap();
    assert!(px >= 14.0, "base font {px} px");
    // Clipped points: each red edge marker is counted in words. The innovations start from a
    // wide prior, beyond the frame of the bulk: at least that figure clips.
    let notes = page
        .matches(" the frame (clipped, marked at the edge)")
        .count();
    let markers = page
        .split("<polygon")
        .skip(1)
        .filter(|p| p.split('>').next().unwrap_or("").contains("#C81E1E"))
        .count();
    assert!(
        notes >= 1 && markers >= 1,
        "notes {notes}, markers {markers}"
    );
    // Long lists open in place: every "… N more" is a <details>' summary.
    for (i, _) in page.match_indices("… ") {
        let rest = &page[i + "… ".len()..];
        if rest.starts_with(|c: char| c.is_ascii_digit()) || rest.starts_with("and ") {
            assert!(
                page[..i].ends_with("<summary>"),
                "a list that cannot be opened: {}",
                &page[i..i + 40]
            );
        }
    }
    // Backticks rendered: the verdicts name `acc-bias` as <code>.
    assert!(!page.contains('`'), "a backtick left as text");
    assert!(page.contains("<code>acc-bias</code>"));
}

/// Issue 29 item 7: `report A.csv B.csv` shows the joint fit `identify A.csv B.csv` makes — two
/// short runs of the paper's system, level and at (90°, 0°, 90°). The page has each run's
/// section (its residual, whitened innovations, NIS and ACF figures, its whiteness and a row of
/// the consistency table), the shared coefficients as `identify` computes them (the same
/// estimate ± 1σ, digit for digit: one fit, one formatting rule), the verdict and the
/// provenance; it exits as `identify` does on the same runs.
#[test]
fn a_joint_report_shows_each_run_and_the_shared_coefficients() {
    let tmp = temp_dir("joint-report");
    let dir = tmp.path();
    let args = |o: &'static str, seed: &'static str| {
        [
            "--hours",
            "12",
            "--rate-s",
            "30",
            "--seed",
            seed,
            "--initial-orientation-deg",
            o,
        ]
    };
    let a = simulate_to(dir, "a.csv", &args("0,0,0", "21"));
    let b = simulate_to(dir, "b.csv", &args("90,0,90", "22"));
    let id = driftid()
        .arg("identify")
        .args([&a, &b])
        .arg("--json")
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&id.stdout).unwrap();
    let html = dir.join("joint.html");
    let out = driftid()
        .arg("report")
        .args([&a, &b])
        .arg("-o")
        .arg(&html)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(matches!(out.status.code(), Some(0 | 3)), "{stderr}");
    assert_eq!(out.status.code(), id.status.code(), "{stderr}");
    let page = std::fs::read_to_string(&html).unwrap();
    // The verdict block first, as trusted as identify's result.
    let state = if v["trusted"] == serde_json::json!(true) {
        "class=\"headline trusted\"><p class=\"state\">TRUSTED</p>"
    } else {
        "class=\"headline untrusted\"><p class=\"state\">NOT TRUSTED</p>"
    };
    let verdict = page.find(state).expect("the verdict block");
    assert!(
        verdict < page.find("<h2").unwrap(),
        "the verdict comes first"
    );
    // Both runs' sections, each with its four figures and its whiteness; a consistency row each.
    for (k, name) in [(1, "a.csv"), (2, "b.csv")] {
        assert!(
            page.contains(&format!("<h2 id=\"run{k}\">Run {k}: {name}</h2>")),
            "no section of run {k}"
        );
        assert!(page.contains(&format!("<tr><td class=\"l\">{name}</td>")));
        for stem in ["residual", "whitened", "nis", "acf"] {
            assert!(
                page.contains(&format!("{stem}-run{k}]")),
                "{stem} of run {k}"
            );
        }
    }
    assert_eq!(page.matches("<svg").count(), 8, "4 figures per run");
    assert_eq!(
        page.matches("<p>Whiteness of the whitened innovations: Ljung–Box Q = ")
            .count(),
        2
    );
    // The shared coefficients: identify's estimate ± 1σ total, written by the one formatting rule.
    let section = &page[page.find("<h2 id=\"coefficients\">").expect("coefficients")..];
    let coefs = v["coefficients"].as_object().unwrap();
    assert_eq!(coefs.len(), 12);
    for (name, c) in coefs {
        let cell = host_tool::format::pm(
            c["value"].as_f64().unwrap(),
            c["sigma_total"].as_f64().unwrap(),
        );
        assert!(
            section.contains(&format!(
                "<td class=\"l\">{name}</td><td class=\"l\">{}</td><td>{cell}</td>",
                c["unit"].as_str().unwrap()
            )),
            "{name}: {cell} not in the table"
        );
    }
    // Every link of the contents lands; the provenance names the command.
    let toc = &page[page.find("<nav class=\"toc\">").unwrap()..];
    let toc = &toc[..toc.find("</nav>").unwrap()];
    for id in toc
        .split("href=\"#")
        .skip(1)
        .map(|l| &l[..l.find('"').unwrap()])
    {
        assert!(page.contains(&format!(" id=\"{id}\"")), "no #{id}");
    }
    assert!(page.contains("How this page was made") && page.contains("report "));
    assert_eq!(
        page.matches("<div class=\"scroll\"><table>").count(),
        page.matches("<table>").count()
    );
}

/// Issue 28 item 6: time stamps no clock's jitter explains (intervals of 1.25, 1, 1.5, 0.7 s
/// after six regular samples: no run of four within 10 % of equal spacing) are refused naming
/// the file and the CSV line of the first irregular row — sample 7, t = 6.25 s, on line 10 after
/// a metadata line, a comment and the header — not a sample index; exit 2, for every command
/// that prepares the recording.
#[test]
fn irregular_time_stamps_are_refused_naming_the_line() {
    let tmp = temp_dir("irregular");
    let dir = tmp.path();
    let csv = dir.join("irregular.csv");
    let mut text =
        String::from("# latitude_deg: 39.1\n# a logger's file\nt_s,ax_mps2,ay_mps2,az_mps2\n");
    let steps = [1.25, 1.0, 1.5, 0.7];
    let mut t: f64 = 0.0;
    for k in 0..60 {
        if k > 0 {
            t += if k < 6 { 1.0 } else { steps[(k - 6) % 4] };
        }
        // Noise-like readings of about 1e-4 m/s² around a level platform's gravity.
        let n = |a: f64| 1e-4 * (k as f64 * a).sin();
        text += &format!("{t:.3},{},{},{}\n", n(1.7), n(2.3), 9.8 + n(3.1));
    }
    assert!(text.lines().nth(9).unwrap().starts_with("6.250,"));
    std::fs::write(&csv, text).unwrap();
    for cmd in ["identify", "diagnose", "report"] {
        let mut args: Vec<std::ffi::OsString> = vec![cmd.into(), csv.clone().into()];
        if cmd == "report" {
            args.extend(["-o".into(), dir.join("r.html").into()]);
        }
        let (code, all) = run_driftid(&args);
        assert_eq!(code, Some(2), "{cmd}: {all}");
        assert!(
            all.contains(&format!(
                "{}:10: the recording cannot support an estimate",
                csv.display()
            )) && all.contains("the times are irregular from t = 6.25 s"),
            "{cmd}: {all}"
        );
    }
}

/// `driftid COMMAND CSV --truth CSV's truth --json`: its exit status, its JSON and all it
/// printed (for the assertion messages).
fn json_with_truth(
    command: &str,
    csv: &std::path::Path,
) -> (Option<i32>, serde_json::Value, String) {
    let truth = csv.with_extension("truth.json");
    let out = driftid()
        .args([
            command.as_ref(),
            csv.as_os_str(),
            "--truth".as_ref(),
            truth.as_os_str(),
            "--json".as_ref(),
        ])
        .output()
        .unwrap();
    let all =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    let v = serde_json::from_slice(&out.stdout).unwrap_or(serde_json::Value::Null);
    (out.status.code(), v, all)
}

/// Every coefficient of `v` within `bound` of its total 1σ; returns how many there were.
fn within_total_sigma(v: &serde_json::Value, bound: f64, what: &str) -> usize {
    let coefs = v["coefficients"].as_object().unwrap();
    for (name, c) in coefs {
        let z = c["error"].as_f64().unwrap() / c["sigma_total"].as_f64().unwrap();
        assert!(z.abs() <= bound, "{what} {name}: {z:.2} σ off");
    }
    coefs.len()
}

/// Issue 27 item 2 (the gyro half): a drift step of 0.002 deg/h on Y at 30 h of 60 (60 h at
/// 10 s, seed 5) is an explanation like any other. Before, `identify` named it "not repaired"
/// (exit 3) and `diagnose` let `drift-markov` absorb it although the step's evidence gain was
/// larger. Now `identify` repairs it (a `drift-step` finding, the step modelled from its time on)
/// and exits 0; `diagnose` adds `drift-step` on the ladder. Tolerances: the step's time within
/// ±0.25 h (the profile's grid is the 60-s period; measured 29.99 h); every coefficient (the 12
/// and the step's three) within 3.5 of its total 1σ — 15 coefficients at 3.5σ fail together with
/// probability ≈ 0.7 % for an honest 1σ, and an unrepaired step puts DXx ~40σ off.
#[test]
fn a_drift_step_is_repaired_by_name_when_it_beats_every_explanation() {
    let tmp = temp_dir("drift-step");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--seed",
            "5",
            "--rate-s",
            "10",
            "--effect",
            "drift-step=0,0.002,0:30",
        ],
    );
    let (code, v, all) = json_with_truth("identify", &csv);
    assert_eq!(code, Some(0), "{all}");
    let step = v["data_quality"]["findings"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["kind"] == "drift-step")
        .unwrap_or_else(|| panic!("no drift-step finding: {all}"));
    assert_eq!(step["action"], "repaired");
    let t0_h = step["start_s"].as_f64().unwrap() / 3600.0;
    assert!((t0_h - 30.0).abs() <= 0.25, "step at {t0_h} h");
    assert_eq!(within_total_sigma(&v, 3.5, "identify"), 15);
    let (code, all) = run_driftid(&["diagnose".into(), csv.into()]);
    assert_eq!(code, Some(0), "{all}");
    assert!(all.contains("paper + drift-step "), "{all}");
}

/// A gyro warm-up transient, 0.004 deg/h per axis decaying with τ = 3 h (60 h at 10 s, seed 5):
/// not in the catalog before, and with the drift step among the candidates a step at the
/// warm-up's knee explained it (exit 0, `drift-step` named, coefficients 2.7–3.5σ off on four
/// seeds). Now `diagnose` adds `drift-warmup` (τ profiled) and is trusted; every coefficient (the
/// 12 and the three amplitudes) within 3.5 of its total 1σ — 15 at 3.5σ fail together with
/// probability ≈ 0.7 % for an honest 1σ; the step's answer put DZ0 3.45σ off.
#[test]
fn a_warm_up_transient_is_named_and_its_coefficients_hold() {
    let tmp = temp_dir("warmup");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--seed",
            "5",
            "--rate-s",
            "10",
            "--effect",
            "drift-transient=0.004,0.004,0.004:3",
        ],
    );
    let (code, v, all) = json_with_truth("diagnose", &csv);
    assert_eq!(code, Some(0), "{all}");
    let last = v["ladder"].as_array().unwrap().last().unwrap();
    assert_eq!(last["model"], serde_json::json!(["drift-warmup"]), "{all}");
    assert_eq!(within_total_sigma(&v, 3.5, "diagnose"), 15);
}

/// Clean 24-h runs at 10 s (issue 26's false-alarm sweep): 3 of 8 seeds (101, 106, 108) exited
/// 3 because the catalog's `drift-daily` stayed within the plausible margin of "no effect" — one
/// daily cycle is confounded with the constant drifts — although the total 1σ already carries a
/// daily drift as a set-up parameter sized by the data. Those three seeds must now be trusted,
/// with every drift coefficient within 3.5 of its total 1σ (measured ≤ 2.2σ over 40 clean
/// seeds, 40/40 trusted; 12 at 3.5σ fail together with probability ≈ 0.6 % per run).
#[test]
fn clean_day_long_runs_are_not_distrusted_for_slow_drifts_they_carry() {
    let tmp = temp_dir("clean-24h");
    let dir = tmp.path();
    // Seed 1079: the data moved the latitude by noise (evidence gain 2.8) and the run was
    // distrusted as "resting on the assumed latitude prior" (1 of 100 clean runs); a move the
    // data do not establish (gain < 10) is no such reason.
    // Seeds 28, 63, 72, 96: with `drift-trend`'s prior on the drift effects' one size (0.01 deg/h
    // a day) the catalog trend stayed within the plausible margin and moved DXy or DZy by
    // 1.9–3.3 total σ (4 of 100 clean runs exit 3); the trend is now carried as a set-up drift.
    for seed in ["101", "106", "108", "1079", "28", "63", "72", "96"] {
        let csv = simulate_to(
            dir,
            &format!("c{seed}.csv"),
            &["--seed", seed, "--hours", "24", "--rate-s", "10"],
        );
        let (code, v, all) = json_with_truth("identify", &csv);
        assert_eq!(code, Some(0), "seed {seed}: {all}");
        within_total_sigma(&v, 3.5, &format!("seed {seed}"));
    }
}

/// Issue 26 item 2: explanations that compete. A drift trend (1e-5 deg/h/h per axis) with a
/// drift step (0.002 deg/h on X at 40 h), 60 h at 10 s, seed 33: the ladder added the step, then
/// `drift-daily` beat `drift-trend` by 12 (−2 ln units, "very strong") and `diagnose` exited 0
/// with DXx 6.4σ off its total 1σ. The two rivals disagree on DXx by ~7σ of their 1σ, so the
/// choice is not settled: exit 3, naming both.
#[test]
fn explanations_within_the_margin_that_disagree_are_not_trusted() {
    let tmp = temp_dir("confounded");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--seed",
            "33",
            "--rate-s",
            "10",
            "--effect",
            "drift-trend=1e-5,1e-5,-1e-5",
            "--effect",
            "drift-step=0.002,0,0:40",
        ],
    );
    let (code, v, all) = json_with_truth("diagnose", &csv);
    assert_eq!(code, Some(3), "{all}");
    let reasons = v["untrusted_reasons"].to_string();
    assert!(
        reasons.contains("both explain the data") && reasons.contains("`drift-trend`"),
        "{all}"
    );
}

/// Issue 26: each run's set-up is a nuisance of the joint fit. Two runs (36 h at 10 s) whose
/// latitude, clock rate, gravity and start attitude are off by draws from the priors (seeds 45
/// and 47): the joint fit fused the runs' fits at their *stated* set-ups and added the set-ups'
/// spread afterwards, so "the joint model does not explain this run" (NIS/3 ≈ 5.6) for both runs
/// and DXx 6.7σ off its total 1σ. Now each run's fit is taken at its settled set-up and widened
/// by what the set-up leaves uncertain before fusing (docs/model.md, "Several runs"): both runs
/// are explained, and every coefficient is within 3.5 of its total 1σ (over 25 such pairs the
/// RMS error/total 1σ was 0.77 and none beyond 3σ; 24 coefficients at 3.5σ fail together with
/// probability ≈ 1 % for an honest 1σ). The noise-only 1σ stays the smaller one.
#[test]
fn each_runs_set_up_is_marginalised_in_a_joint_fit() {
    let tmp = temp_dir("joint-nuisance");
    let dir = tmp.path();
    for seed in [45u32, 47] {
        let run = |name: &str, s: u32| {
            let s = s.to_string();
            let args = ["--seed", &s, "--hours", "36", "--rate-s", "10"];
            let mut args = args.to_vec();
            // The set-up's knobs and start drawn; no drift trend (drawn from its prior it is
            // mostly detectable at 36 h: an effect for `diagnose`, not this test's subject).
            args.extend([
                "--setup-errors-from-priors",
                "--drift-trend-error-deg-h-per-h",
                "0,0,0",
            ]);
            simulate_to(dir, name, &args)
        };
        let a = run(&format!("a{seed}.csv"), seed);
        let b = run(&format!("b{seed}.csv"), seed + 1000);
        let out = driftid()
            .arg("identify")
            .args([&a, &b])
            .arg("--truth")
            .arg(a.with_extension("truth.json"))
            .arg("--json")
            .output()
            .unwrap();
        let all = String::from_utf8_lossy(&out.stdout).to_string()
            + &String::from_utf8_lossy(&out.stderr);
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect(&all);
        let reasons = v["untrusted_reasons"].to_string();
        assert!(
            !reasons.contains("does not explain this run"),
            "seed {seed}: {reasons}"
        );
        within_total_sigma(&v, 3.5, &format!("seed {seed}"));
        for (name, c) in v["coefficients"].as_object().unwrap() {
            let (noise, total) = (
                c["sigma"].as_f64().unwrap(),
                c["sigma_total"].as_f64().unwrap(),
            );
            assert!(
                noise <= total * (1.0 + 1e-9),
                "seed {seed} {name}: {noise} > {total}"
            );
        }
    }
}

/// Runs of two different systems are not fused silently: the same seeds as a clean pair, but the
/// second run's X gyro drifts 0.003 deg/h more (a drift step at t = 0, ~7 of DX0's total 1σ).
/// Each run alone is explained by the paper's model, so only the runs' agreement can tell: each
/// run's coefficients against the joint ones, χ² over the total covariance (p 2e-5 and 2e-6
/// measured; p < 1e-3 fails). The clean pair agrees (p 0.45–0.57) and is trusted.
#[test]
fn runs_whose_coefficients_disagree_are_not_trusted() {
    let tmp = temp_dir("joint-disagree");
    let dir = tmp.path();
    let common = ["--rate-s", "10", "--hours", "36"];
    let a = simulate_to(dir, "a.csv", &[&common[..], &["--seed", "2"]].concat());
    let level = ["--seed", "3", "--initial-orientation-deg", "0,0,90"];
    let b = simulate_to(dir, "b.csv", &[&common[..], &level].concat());
    let c = simulate_to(
        dir,
        "c.csv",
        &[&common[..], &level, &["--effect", "drift-step=0.003,0,0:0"]].concat(),
    );
    for (other, code) in [(&b, 0), (&c, 3)] {
        let (got, all) = run_driftid(&["identify".into(), a.clone().into(), other.clone().into()]);
        assert_eq!(got, Some(code), "{all}");
        assert_eq!(
            all.contains("disagree with the other runs'"),
            code == 3,
            "named exactly when it is so:\n{all}"
        );
    }
}

/// `identify --single-pass` (the paper's one EKF pass, no smoother) panicked (exit 101) once the
/// set-up was settled after every fit: a single pass weighs no set-up knobs, and the settling
/// indexed them anyway. It prints the pass's estimates with their 1σ and exits as a computed
/// result (0 or 3), never a crash.
#[test]
fn a_single_pass_identifies_without_a_crash() {
    let tmp = temp_dir("single-pass");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &["--hours", "12", "--rate-s", "10", "--seed", "3"],
    );
    let (code, all) = run_driftid(&["identify".into(), csv.into(), "--single-pass".into()]);
    assert!(matches!(code, Some(0 | 3)), "{all}");
    assert!(all.contains("DXx") && !all.contains("panicked"), "{all}");
}

/// The truth of a parameter, one rule for every command (issue 30): the simulator knows the
/// catalog's parameters (0 when not injected) but not an effects file's, which the user names:
/// `identify --truth` reported KNx's truth as 0 (an error of the whole estimate, 2e-3 m/s²)
/// for the example `acc-north` file on a run made with `simulate --effect acc-north`. Now
/// unknown: no truth or error for KN, and the paper's coefficients keep theirs.
#[test]
fn an_effects_file_parameter_has_no_truth_the_simulator_cannot_know() {
    let tmp = temp_dir("file-truth");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "north.csv",
        &[
            "--hours",
            "12",
            "--rate-s",
            "10",
            "--seed",
            "7",
            "--effect",
            "acc-north=2e-3,-1.5e-3,1e-3",
        ],
    );
    let file =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/effects/acc-north.toml");
    let out = driftid()
        .arg("identify")
        .arg(&csv)
        .arg("--effects")
        .arg(&file)
        .args(["--with", "acc-north", "--json", "--truth"])
        .arg(csv.with_extension("truth.json"))
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|_| panic!("{}", String::from_utf8_lossy(&out.stderr)));
    let c = &v["coefficients"];
    for k in ["KNx", "KNy", "KNz"] {
        assert!(
            c[k]["truth"].is_null() && c[k]["error"].is_null(),
            "{k}: {}",
            c[k]
        );
    }
    assert_eq!(c["DXx"]["truth"], serde_json::json!(-0.1));
}

/// Latitudes written without decimals (a prior of 0.29°) away from 39°: the data measure the
/// latitude only together with gravity near the equator, and the set-up's quadratic model from
/// refits at ±1 prior σ (100 of the data's 1σ) put a latitude written "20" at −550° and, with a
/// first fix, one written "10" at 9.51° with DZx 11.6 of its total 1σ off, exit 0. Refits now
/// converge, and steep directions are refitted at two of the data's 1σ along the Hessian's
/// eigendirections: every run is either not trusted or within 3.5 of its total 1σ (12
/// coefficients at 3.5σ fail together with probability ≈ 0.6 % for an honest 1σ), and none
/// ends in an error (a refit's third pass diverged at "30": the one pass then stands). Measured
/// on this seed: all six trusted, worst 0.6–1.4 total 1σ.
#[test]
fn runs_at_low_latitudes_are_never_confidently_wrong() {
    never_confidently_wrong_at(
        "low-latitude",
        "4003",
        &["30", "20", "10", "0", "-5", "-20"],
    );
}

/// 24-h runs at 10 s of `seed` at each latitude of `lats` (written as given): `identify` ends in
/// exit 0 or 3, and a trusted answer lies within 3.5 of its total 1σ.
fn never_confidently_wrong_at(tag: &str, seed: &str, lats: &[&str]) {
    let tmp = temp_dir(tag);
    let dir = tmp.path();
    for lat in lats {
        let csv = simulate_to(
            dir,
            &format!("lat{lat}.csv"),
            &[
                "--hours",
                "24",
                "--rate-s",
                "10",
                "--seed",
                seed,
                &format!("--latitude-deg={lat}"),
            ],
        );
        let (code, v, all) = json_with_truth("identify", &csv);
        assert!(matches!(code, Some(0 | 3)), "latitude {lat}: {all}");
        if code == Some(0) {
            within_total_sigma(&v, 3.5, &format!("latitude {lat}"));
        }
    }
}

/// A drift trend (2.3e-5 deg/h per h on X) with set-up errors drawn from the priors, 36 h at 10 s
/// (seed 19): the latitude, bent by the trend, left the stated "39.1"'s bound, and a clock
/// "1043 ppm fast" (the truth: 19 ppm) beat every catalog effect by taking the gravity's move
/// (10 ppm, within its prior) along — 2300 against the trend's 250, weighed with the set-up as
/// stated — was repaired, and DY0 ended 8.7 of its total 1σ off, exit 0. The catalog's effects
/// are now also weighed with the set-up within its priors, the best refitted with it
/// marginalised (the trend: 2291, within the confounded margin of the clock's 2300): no repair,
/// exit 3; `diagnose`, which repaired it on its own path, adds acc-bias and the trend, exit 3.
/// Tolerance: a trusted answer within 3.5 total σ, as in the tests above.
#[test]
fn a_trend_with_a_moved_set_up_is_not_repaired_as_a_fast_clock() {
    let tmp = temp_dir("trend-clock");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--seed",
            "19",
            "--hours",
            "36",
            "--rate-s",
            "10",
            "--setup-errors-from-priors",
            "--drift-trend-error-deg-h-per-h",
            "0,0,0",
            "--effect",
            "drift-trend=2.3378866106855908e-05,3.2231424519926477e-06,-1.8108150405487541e-06",
        ],
    );
    for command in ["identify", "diagnose"] {
        let (code, v, all) = json_with_truth(command, &csv);
        assert!(matches!(code, Some(0 | 3)), "{command}: {all}");
        if code == Some(0) {
            within_total_sigma(&v, 3.5, &format!("{command}: trend with set-up errors"));
        }
        // `diagnose` repaired the clock on its own path before its ladder (then exit 3 for
        // other reasons): a cause stated with certainty that the data do not single out.
        assert!(
            !v["data_quality"]
                .to_string()
                .contains("clock rate is misstated"),
            "{command}: {all}"
        );
    }
}

/// A level start at exactly 30° S sits on the border of the two charts of the platform angles
/// (its daily turn reaches ty = 60°): the set-up's refits at the latitude ± its prior σ chose
/// the other chart, started from the stated fit's trajectory 60° off, and diverged, and the run
/// ended in exit 2 ("the set-up's posterior could not be formed"; seed 7001, 2 of 3 seeds).
/// The moved set-ups now keep the chart (the knobs' signature and the misstated set-up's
/// refits). Tolerance 3.5 total σ as in the test above; measured on this seed
/// (both signs): exit 0, worst 1.03 and 1.36 total σ.
#[test]
fn a_start_on_the_charts_border_is_identified() {
    never_confidently_wrong_at("chart-border", "7001", &["-30", "30"]);
}

/// The set-up taken as exact (every prior 0, as the message for a set-up that cannot be
/// marginalised advises) is identified without a crash: the refits' design had no knob left and
/// an eigen-decomposition of an empty matrix panicked (exit 101).
#[test]
fn a_set_up_taken_as_exact_identifies_without_a_crash() {
    let tmp = temp_dir("exact-setup");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &["--hours", "12", "--rate-s", "10", "--seed", "8"],
    );
    let exact = [
        "--latitude-sigma-deg",
        "0",
        "--clock-sigma-ppm",
        "0",
        "--gravity-sigma-ppm",
        "0",
    ];
    let mut args: Vec<std::ffi::OsString> = vec!["identify".into(), csv.into()];
    args.extend(exact.iter().map(Into::into));
    let (code, all) = run_driftid(&args);
    assert!(matches!(code, Some(0 | 3)), "{all}");
    assert!(all.contains("DXx") && !all.contains("panicked"), "{all}");
}

/// Found by a sweep of random recordings: a turn-on transient with set-up errors from the priors
/// (24 h at 30 s, 60.25° N, seed 1129) was repaired by `diagnose` as a clock 4367 ppm fast: it
/// beat the set-up moved within its priors by 26, while the data did not contradict the stated
/// set-up, so the catalog's effects with the set-up moved were never weighed (acc-bias and a
/// trend together explain more); DZ0 ended 5.1σ off, exit 0. A repair must beat them, and the
/// best pair, whether or not the set-up is contradicted.
#[test]
fn a_transient_is_not_repaired_as_a_clock_thousands_of_ppm_fast() {
    let tmp = temp_dir("transient-clock");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--seed",
            "1129",
            "--hours",
            "24",
            "--rate-s",
            "30",
            "--latitude-deg=60.25",
            "--setup-errors-from-priors",
            "--effect",
            "drift-transient=-0.00458,0.00564,0.00396:5",
        ],
    );
    let (code, v, all) = json_with_truth("diagnose", &csv);
    assert!(matches!(code, Some(0 | 3)), "{all}");
    assert!(
        !v["data_quality"]
            .to_string()
            .contains("clock rate is misstated"),
        "{all}"
    );
    // Then the ladder chose acc-bias and a trend (gain 435.7) over the warm-up (433.0 at its best
    // τ, 5.7 h), and was trusted with DYx 4.3 total σ off; warm-ups of 3–4 h, within the
    // confounded margin, put DYx where the truth is. Named or covered: exit 3, or every drift
    // coefficient within 3 total σ (3σ: 12 coefficients of an honest 1σ all within it with
    // probability 97 %).
    if code == Some(0) {
        drift_within_total_sigma(&v, 3.0, "transient");
    }
}

/// The paper's 12 drift coefficients of `v` within `bound` of their total 1σ.
fn drift_within_total_sigma(v: &serde_json::Value, bound: f64, what: &str) {
    let coefs = v["coefficients"].as_object().unwrap();
    for (name, c) in coefs
        .iter()
        .filter(|(n, _)| n.starts_with('D') && n.len() == 3)
    {
        let z = c["error"].as_f64().unwrap() / c["sigma_total"].as_f64().unwrap();
        assert!(z.abs() <= bound, "{what} {name}: {z:.2} σ off");
    }
}

/// A g² drift of ~2e-5 deg/h/(m/s²)² per term (a random recording: 36 h at 30 s, 51.5° N, set-up
/// errors drawn from the priors, started at 90°, 20°, 90°). With g2's catalog prior at 0.01
/// (~1 deg/h at 1 g², 100× the drift effects' one size) its 15 parameters paid ~100 units more
/// than `drift-daily`; it lost by 44 and the run was trusted as acc-scale + drift-daily +
/// drift-trend with DZy 5.8 total σ off. At 1e-3 `g2` joins the model, and the run is trusted
/// only with every drift coefficient within 3 total σ (measured: g2 chosen, 1.4σ).
#[test]
fn a_small_g2_drift_is_named_g2_not_a_daily_drift() {
    let tmp = temp_dir("g2-small");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--seed",
            "1243",
            "--hours",
            "36",
            "--rate-s",
            "30",
            "--latitude-deg=51.5",
            "--setup-errors-from-priors",
            "--initial-orientation-deg",
            "90,20,90",
            "--effect",
            "g2=1.1e-05,-1.5e-05,-1.6e-05,1.1e-05,2.3e-05,-1.6e-05,1.8e-06,1.8e-05,2.1e-05,-2.1e-05,2.5e-05,1.5e-05,2.9e-05,-1.7e-06,-4.5e-06,-1.5e-05,2e-05,2.1e-05",
        ],
    );
    let (code, v, all) = json_with_truth("diagnose", &csv);
    assert!(matches!(code, Some(0 | 3)), "{all}");
    let last = v["ladder"].as_array().and_then(|l| l.last()).unwrap();
    assert!(
        last["model"].to_string().contains("\"g2\""),
        "{}",
        last["model"]
    );
    if code == Some(0) {
        drift_within_total_sigma(&v, 3.0, "g2");
    }
}

/// A 12-h periodic gyro drift is outside the fixed catalog (`drift-daily` is the solar day's):
/// on two random recordings (36 h at 10 s) it was absorbed by `drift-daily`, the final model
/// consistent, and trusted with DYy and DZy 7.6 and 11 total σ off. `diagnose` now profiles a
/// cycle's period: the first rung names `drift-periodic` with a period within 5 % of 12 h (the
/// fine grid's step is 3 %; over three cycles a 5 % error is a phase error of 0.9 rad at the
/// end) — or `g2`, whose products of the turning gravity components hold the same twice-daily
/// cycle on a static run (on seed 1211 g2 won by 0.1 with the coefficients within 0.9σ) — never
/// `drift-daily`; and it is trusted only with every drift coefficient within 3 total σ.
#[test]
fn a_twelve_hour_drift_cycle_is_named_with_its_period() {
    let tmp = temp_dir("cycle-12h");
    let dir = tmp.path();
    for (seed, lat, amplitudes) in [
        ("1211", "-30.3", "0.000638,-0.000465,-0.000757"),
        ("1203", "51.5", "0.000586,-0.000478,-0.000484"),
    ] {
        let csv = simulate_to(
            dir,
            &format!("run{seed}.csv"),
            &[
                "--seed",
                seed,
                "--hours",
                "36",
                "--rate-s",
                "10",
                &format!("--latitude-deg={lat}"),
                "--effect",
                &format!("drift-sine={amplitudes}:12"),
            ],
        );
        let (code, v, all) = json_with_truth("diagnose", &csv);
        assert!(matches!(code, Some(0 | 3)), "{all}");
        let reason = v["ladder"][0]["next_reason"].as_str().unwrap_or_default();
        if !reason.starts_with("`g2`") {
            let period: f64 = reason
                .split("a period of ")
                .nth(1)
                .and_then(|r| r.split(' ').next())
                .and_then(|p| p.parse().ok())
                .unwrap_or_else(|| panic!("seed {seed}: neither a period nor g2: {reason}"));
            assert!((period / 12.0 - 1.0).abs() < 0.05, "seed {seed}: {reason}");
        }
        if code == Some(0) {
            drift_within_total_sigma(&v, 3.0, &format!("seed {seed}"));
        }
    }
}

/// Issue 26, found by two-effect random recordings: a g² drift of ~2e-5 deg/h/(m/s²)² per term
/// with an accelerometer bias, 24 h at 1 s. No test can see this g² drift (its score test: 15.2
/// on 15 dof, p = 0.44), yet it moves DXz by 12.7 total σ: one day from one orientation cannot
/// tell a g² drift of that size from the coefficients. The paper's model assumes it absent; the
/// tool may trust the run only saying so. Weighing g2 over prior scales ×1, ×0.3, ×0.1 distrusted
/// 14 of 30 clean 24-h runs; carrying it at 1e-5 per term in the total 1σ would widen DX0, DXy,
/// DXz, DYz and DZy by ~2× on every clean run of the paper's model. So: exit 3, or every drift
/// coefficient beyond 3 total σ marked as holding only on g2's absence (`conditional_on`, in the
/// text "could move, at a size this run cannot rule out").
#[test]
fn a_small_g2_drift_under_an_accelerometer_bias_is_distrusted_or_marked_conditional() {
    let tmp = temp_dir("g2-under-bias");
    let dir = tmp.path();
    let csv = simulate_to(
        dir,
        "run.csv",
        &[
            "--seed",
            "5052",
            "--hours",
            "24",
            "--rate-s",
            "1",
            "--latitude-deg=51.5",
            "--effect",
            "acc-bias=-8.36e-05,8.9e-05,0.000144",
            "--effect",
            "g2=2.3e-06,1.3e-05,1.5e-07,2.6e-05,2.5e-05,2.6e-05,2.1e-05,1.4e-05,1.1e-05,-2e-05,-2.8e-05,-2.9e-05,-2e-05,-5.9e-06,-6e-06,6.1e-06,-2.1e-05,2.6e-05",
        ],
    );
    let (code, v, all) = json_with_truth("diagnose", &csv);
    assert!(matches!(code, Some(0 | 3)), "{all}");
    if code == Some(0) {
        for (name, c) in v["coefficients"].as_object().unwrap() {
            let z = c["error"].as_f64().unwrap() / c["sigma_total"].as_f64().unwrap();
            let on_g2 = c["conditional_on"]
                .as_array()
                .unwrap()
                .iter()
                .any(|e| e["effect"] == "g2");
            assert!(
                !(name.starts_with('D') && name.len() == 3) || z.abs() <= 3.0 || on_g2,
                "{name}: {z:.1} total σ off, not marked as holding only on g2's absence: {}",
                c["conditional_on"]
            );
        }
    }
}

/// A latitude written degrees off, 30 h at 10 s. With the site's own gravity in the metadata
/// (`simulate --latitude-error-deg 2`, seed 7: the platform at 37.1°, "39.1" written) `diagnose`
/// told the misfit as a drift trend and a daily drift and trusted it with DYy 56σ off: the
/// latitude profile moved gravity with the latitude and so never reached a site whose gravity is
/// not the normal gravity of its latitude. Now it exits 3 naming the site's latitude (as a
/// finding confounded with the drift trend: the 2° pay the gravity prior 36 and the prior odds
/// of a misstatement). With no gravity in the metadata (the data's gravity the normal gravity of
/// 38.1°, "39.1" written, seed 8) the latitude is named alone, with a rerun advised; that rerun
/// once took the data's latitude as exact, and a latitude 1σ (0.02°) from the site's moved the
/// drifts by 24–28σ, trusted. Now the advice carries the latitude's 1σ, and the rerun is trusted
/// and right. Tolerances: the named latitude within 3 of its 1σ (measured on the 25 of 32 runs that
/// name it, 0.3°–5° off, both gravity conventions: −1.2σ to +2.2σ); after the rerun every drift coefficient within
/// 3 total σ (measured 0.9–1.9σ on five reruns).
#[test]
fn a_latitude_degrees_off_is_named_and_its_advised_rerun_is_right() {
    let tmp = temp_dir("latitude-degrees-off");
    let dir = tmp.path();
    let run = ["--hours", "30", "--rate-s", "10"];
    let own_gravity = simulate_to(
        dir,
        "own-gravity.csv",
        &[&run[..], &["--seed", "7", "--latitude-error-deg", "2"]].concat(),
    );
    let at_38_1 = simulate_to(
        dir,
        "at-38.1.csv",
        &[&run[..], &["--seed", "8", "--latitude-deg", "38.1"]].concat(),
    );
    let text = std::fs::read_to_string(&at_38_1).unwrap();
    let written: String = text
        .lines()
        .filter(|l| !l.starts_with("# gravity_mps2"))
        .map(|l| match l.starts_with("# latitude_deg") {
            true => "# latitude_deg: 39.1\n".to_string(),
            false => format!("{l}\n"),
        })
        .collect();
    std::fs::write(&at_38_1, written).unwrap();
    for (csv, truth, advised) in [(own_gravity, 37.1, false), (at_38_1, 38.1, true)] {
        let (code, _, all) = json_with_truth("diagnose", &csv);
        assert_eq!(code, Some(3), "{truth}: {all}");
        let finding = all
            .lines()
            .find(|l| l.trim_start().starts_with("- latitude"))
            .unwrap_or_else(|| panic!("{truth}: no latitude finding:\n{all}"));
        let named = finding
            .split("at latitude ")
            .nth(1)
            .and_then(|s| s.split(" deg").next())
            .and_then(|s| s.split_once(" ± "))
            .map(|(l, s)| (l.parse::<f64>().unwrap(), s.parse::<f64>().unwrap()))
            .unwrap_or_else(|| panic!("{truth}: no latitude named: {finding}"));
        assert!(
            (named.0 - truth).abs() <= 3.0 * named.1,
            "named {named:?} for {truth}: {finding}"
        );
        let advice = finding.split("rerun with ").nth(1);
        assert_eq!(advice.is_some(), advised, "{truth}: {finding}");
        let Some(advice) = advice else { continue };
        let options: Vec<&str> = advice
            .split_whitespace()
            .take_while(|w| w.starts_with("--") || w.parse::<f64>().is_ok())
            .collect();
        assert!(
            options.contains(&"--latitude-sigma-deg"),
            "the rerun carries the latitude's 1σ: {advice}"
        );
        let truth_file = csv.with_extension("truth.json");
        let mut args: Vec<std::ffi::OsString> = vec!["diagnose".into(), csv.clone().into()];
        args.extend(options.iter().map(|o| o.into()));
        args.extend(["--truth".into(), truth_file.into(), "--json".into()]);
        let out = driftid().args(&args).output().unwrap();
        let rerun = String::from_utf8_lossy(&out.stderr).to_string();
        assert_eq!(out.status.code(), Some(0), "{options:?}:\n{rerun}");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        drift_within_total_sigma(&v, 3.0, "the advised rerun");
    }
}

/// A latitude 3° off whose repair the warm refit cannot fit (60 h at 10 s, 29° N stated as 32°:
/// the smoother's innovation covariance not positive definite from the stated set-up's fit) is
/// refitted cold at the repaired latitude, not refused: exit 0 with the latitude repaired and
/// named, by `identify` and `diagnose`. Before, exit 2 with the filter's error pointing at the
/// columns. The latitude must lie
/// within 5σ of the truth (measured: 28.9989 ± 0.0011).
#[test]
fn a_repair_the_warm_refit_cannot_fit_is_refitted_cold() {
    let tmp = temp_dir("repair-cold");
    let csv = simulate_to(
        tmp.path(),
        "run.csv",
        &[
            "--hours",
            "60",
            "--rate-s",
            "10",
            "--seed",
            "3",
            "--latitude-deg",
            "32",
            "--latitude-error-deg",
            "3",
        ],
    );
    for command in ["identify", "diagnose"] {
        let out = driftid()
            .args([command.as_ref(), csv.as_os_str(), "--json".as_ref()])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(0), "{command}: {stderr}\n{stdout}");
        let json: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        let message = json["data_quality"]["findings"][0]["message"]
            .as_str()
            .unwrap_or_default();
        let at = message
            .split("the data put it at ")
            .nth(1)
            .and_then(|r| r.split(" deg").next())
            .unwrap_or_default();
        let (l, s) = at.split_once(" ± ").unwrap_or(("nan", "nan"));
        let (l, s): (f64, f64) = (l.parse().unwrap_or(f64::NAN), s.parse().unwrap_or(f64::NAN));
        assert!(
            message.starts_with("the latitude is misstated") && (l - 29.0).abs() <= 5.0 * s,
            "{command}: {message}"
        );
    }
}

/// A model that cannot be fitted at all at the stated latitude (36 h at 5 s, 35° S stated as
/// 45° S: the single EKF pass unhealthy) is refused, exit 2, with the latitude the data put the
/// site at named, not only the filter's error (which points at the columns).
#[test]
fn a_fit_that_fails_at_a_wrong_latitude_names_the_latitude() {
    let tmp = temp_dir("fit-fails-latitude");
    let csv = simulate_to(
        tmp.path(),
        "run.csv",
        &[
            "--hours",
            "36",
            "--rate-s",
            "5",
            "--seed",
            "3",
            "--latitude-deg",
            "-45",
            "--latitude-error-deg",
            "-10",
        ],
    );
    let out = driftid().arg("identify").arg(&csv).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("the model cannot be fitted at the stated latitude -45 deg, but the data put the site at latitude -35.00"),
        "{stderr}"
    );
}
