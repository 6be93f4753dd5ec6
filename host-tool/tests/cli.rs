//! The `driftid` binary as a user runs it: simulate → identify --json, and bad recordings.

use std::path::PathBuf;
use std::process::Command;

fn driftid() -> Command {
    Command::new(env!("CARGO_BIN_EXE_driftid"))
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("driftid-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn simulate_then_identify_json_has_the_documented_fields() {
    let dir = temp_dir("json");
    let csv = dir.join("run.csv");
    let out = driftid()
        .args(["simulate", "--scenario", "paper", "--hours", "36", "--rate-s", "10", "--seed", "3", "--out"])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(out.status.success(), "simulate failed: {}", String::from_utf8_lossy(&out.stderr));
    let out = driftid().arg("identify").arg(&csv).arg("--truth").arg(dir.join("run.truth.json")).arg("--json").output().unwrap();
    assert!(out.status.success(), "identify failed: {}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object on stdout");
    let truth = [0.5, -0.1, -0.05, -0.05, -0.5, 0.05, 0.1, 0.05, 0.5, -0.05, 0.05, -0.1];
    for (k, name) in ["DX0", "DXx", "DXy", "DXz", "DY0", "DYx", "DYy", "DYz", "DZ0", "DZx", "DZy", "DZz"].iter().enumerate() {
        let c = &v["coefficients"][name];
        let (value, sigma) = (c["value"].as_f64().unwrap(), c["sigma"].as_f64().unwrap());
        // 36 h is past one sidereal day: the converged estimate is consistent, so 4σ (a
        // two-sided 6e-5 chance per coefficient) only fails on a real regression.
        assert!(sigma > 0.0 && (value - truth[k]).abs() < 4.0 * sigma, "{name}: {value} ± {sigma}");
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
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_broken_recording_is_a_located_error_not_a_panic() {
    let dir = temp_dir("broken");
    let cases: [(&str, &str, &[&str]); 5] = [
        ("missing.csv", "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2\n0,0,0\n", &["missing.csv", "az_mps2"]),
        ("badnum.csv", "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n1,0,abc,9.8\n", &["badnum.csv:4", "ay_mps2"]),
        ("time.csv", "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n1,0,0,9.8\n1,0,0,9.8\n", &["time.csv:5"]),
        ("nan.csv", "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n1,NaN,0,9.8\n", &["nan.csv:4", "ax_mps2"]),
        ("empty.csv", "", &["empty.csv"]),
    ];
    for (name, text, needles) in cases {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        let out = driftid().arg("identify").arg(&path).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{name}: exit code; stderr: {stderr}");
        assert!(!stderr.contains("panicked"), "{name}: panic: {stderr}");
        for n in needles {
            assert!(stderr.contains(n), "{name}: error should mention `{n}`: {stderr}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn demo_runs_without_arguments() {
    let out = driftid().arg("demo").output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let s = String::from_utf8_lossy(&out.stdout);
    assert!(s.contains("paper T2") && s.contains("DZz") && s.contains("converged"));
}
