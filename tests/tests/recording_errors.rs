//! The recording reader on real files: every defect is reported with the file, the line (and the
//! column where it applies) and the reason; good files round-trip exactly.

use std::path::{Path, PathBuf};

use host_tool::recording::{
    read_recording, write_recording, Metadata, RawSample, RecordingError, RecordingWriter,
};

/// The path `name` in a fresh directory that is removed with what is in it when this is dropped,
/// passed or failed (the suite left its files in the temp directory on every run).
struct Scratch {
    _dir: tempfile::TempDir,
    path: PathBuf,
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

fn scratch(name: &str) -> Scratch {
    let dir = tempfile::Builder::new()
        .prefix("driftid-recording-errors-")
        .tempdir()
        .unwrap();
    Scratch {
        path: dir.path().join(name),
        _dir: dir,
    }
}

fn write(name: &str, bytes: &[u8]) -> Scratch {
    let p = scratch(name);
    std::fs::write(&*p, bytes).unwrap();
    p
}

/// Writes `bytes` to `name`, reads it, expects an error whose message names the file and
/// contains every fragment; returns the error.
fn fails(name: &str, bytes: &[u8], fragments: &[&str]) -> RecordingError {
    let p = write(name, bytes);
    let e = match read_recording(&p) {
        Ok(r) => panic!(
            "{name}: expected an error, read {} samples",
            r.samples.len()
        ),
        Err(e) => e,
    };
    let msg = e.to_string();
    assert!(
        msg.starts_with(&p.display().to_string()),
        "{msg:?} does not start with the path"
    );
    assert!(msg.contains(name), "{msg:?} lacks the file name");
    for f in fragments {
        assert!(msg.contains(f), "{msg:?} lacks {f:?}");
    }
    e
}

const HDR: &str = "# latitude_deg: 39.1\n# description: test\nt_s,ax_mps2,ay_mps2,az_mps2\n";

fn rows(n: usize) -> String {
    (0..n)
        .map(|i| format!("{i}.0,0.001,-0.002,9.8\n"))
        .collect()
}

#[test]
fn not_a_number() {
    let text = format!("{HDR}{}7.0,1.2.3,0,9.8\n", rows(7));
    let e = fails(
        "nan1.csv",
        text.as_bytes(),
        &[":11: column ax_mps2: \"1.2.3\" is not a number"],
    );
    assert_eq!(e.line(), Some(11));
}

#[test]
fn missing_required_column() {
    fails(
        "missing.csv",
        b"# latitude_deg: 39.1\n# x\n\nt_s,ax_mps2,ay_mps2\n0,1,2\n",
        &[":4: missing required column az_mps2 (header has: t_s, ax_mps2, ay_mps2)"],
    );
}

#[test]
fn time_not_increasing() {
    let text = format!("{HDR}{}5.0,0,0,9.8\n", rows(6));
    fails(
        "time.csv",
        text.as_bytes(),
        &[":10: t_s = 5.0 is not after the previous sample's 5.0 (line 9); time must strictly increase"],
    );
}

#[test]
fn no_samples() {
    fails("empty.csv", b"", &[": no samples (file is empty)"]);
    fails(
        "header_only.csv",
        HDR.as_bytes(),
        &[": no samples (header only)"],
    );
    fails(
        "header_only_blank.csv",
        format!("{HDR}\r\n\n").as_bytes(),
        &[": no samples (header only)"],
    );
    fails(
        "comments_only.csv",
        b"# latitude_deg: 1\n",
        &[": no samples (no header row"],
    );
}

#[test]
fn nan_and_infinity_are_bad_samples_not_a_bad_file() {
    // A sensor's NaN/∞ is read as NaN (line kept in `lines`); the data-quality screening then
    // rejects and counts that sample (tests/tests/data_quality.rs) instead of refusing the file.
    for (name, field, col) in [
        ("nan.csv", "3.0,0,NaN,9.8", 1),
        ("inf.csv", "3.0,0,0,-inf", 2),
    ] {
        let text = format!("{HDR}{}{field}\n", rows(3));
        let p = write(name, text.as_bytes());
        let r = read_recording(&p).unwrap();
        assert_eq!(r.samples.len(), 4, "{name}");
        assert!(r.samples[3].specific_force_mps2[col].is_nan(), "{name}");
        assert_eq!(r.lines[3], 7, "{name}");
    }
}

#[test]
fn wrong_number_of_fields() {
    let text = format!("{HDR}{}3.0,0,0,9.8,1\n4.0,0,0,9.8\n", rows(3));
    fails(
        "fields.csv",
        text.as_bytes(),
        &[":7: expected 4 fields (as in the header on line 3), found 5"],
    );
}

#[test]
fn non_utf8() {
    let mut bytes = format!("{HDR}{}", rows(2)).into_bytes();
    bytes.extend_from_slice(b"2.0,0,0,9.8\xc3\x28\n");
    fails("latin.csv", &bytes, &[":6: not valid UTF-8", "0xc3"]);
}

#[test]
fn truncated_last_line_is_dropped_and_reported() {
    let text = format!("{HDR}{}3.0,0.001", rows(3));
    let path = write("cut.csv", text.as_bytes());
    let r = host_tool::recording::read_recording(&path).unwrap();
    assert_eq!(r.samples.len(), 3, "the complete lines are kept");
    assert!(
        r.repairs
            .iter()
            .any(|m| m.contains(":7: truncated last line: 2 of 4 fields and no final newline")),
        "{:?}",
        r.repairs
    );
}

#[test]
fn bad_latitude() {
    fails(
        "lat_range.csv",
        format!(
            "# latitude_deg: -91\nt_s,ax_mps2,ay_mps2,az_mps2\n{}",
            rows(1)
        )
        .as_bytes(),
        &[":1: metadata latitude_deg: -91.0 is outside [-90, 90] degrees"],
    );
    fails(
        "lat_nan.csv",
        format!(
            "# description: x\n# latitude_deg: 39.1N\nt_s,ax_mps2,ay_mps2,az_mps2\n{}",
            rows(1)
        )
        .as_bytes(),
        &[":2: metadata latitude_deg: \"39.1N\" is not a number"],
    );
}

#[test]
fn absurd_magnitude() {
    let text = format!("{HDR}{}2.0,0,1e4,9.8\n", rows(2));
    fails(
        "big.csv",
        text.as_bytes(),
        &[":6: column ay_mps2: 10000.0 m/s^2 is implausibly large (|a| > 1000 m/s^2)"],
    );
}

#[test]
fn missing_file() {
    let p = scratch("does-not-exist.csv");
    let e = read_recording(&p).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("does-not-exist.csv") && msg.contains("cannot open"),
        "{msg}"
    );
}

#[test]
fn crlf_and_trailing_blank_lines_accepted() {
    let text = format!("{HDR}{}\n\n", rows(3)).replace('\n', "\r\n");
    let p = write("crlf.csv", text.as_bytes());
    let r = read_recording(&p).unwrap();
    assert_eq!(r.samples.len(), 3);
    assert_eq!(r.lines, vec![4, 5, 6]);
    assert_eq!(r.meta.latitude_deg, Some(39.1));
    assert_eq!(r.meta.description.as_deref(), Some("test"));
    assert_eq!(r.samples[2].specific_force_mps2, [0.001, -0.002, 9.8]);
}

fn awkward_samples(n: usize, temp: bool) -> Vec<RawSample> {
    // Values whose shortest decimal form is long: round-tripping needs all 17 digits.
    (0..n)
        .map(|i| {
            let x = i as f64;
            RawSample {
                t_s: x / 3.0 + 0.1,
                specific_force_mps2: [
                    (x * 0.7).sin() * 7.6e-4 + 1e-300,
                    std::f64::consts::PI * 1e-3 - x * 1e-9,
                    9.800898 + (x * 1.3).cos() * 1e-4,
                ],
                temp_c: temp.then(|| 20.0 + (x / 7.0).sin() / 3.0),
            }
        })
        .collect()
}

#[test]
fn round_trip_is_exact() {
    let meta = Metadata {
        latitude_deg: Some(-12.345678901234567),
        gravity_mps2: Some(9.781_234_567_890_123),
        description: Some("round trip".into()),
        extra: vec![("rig".into(), "bench 2".into())],
    };
    for temp in [false, true] {
        let samples = awkward_samples(2000, temp);
        let p = scratch(&format!("roundtrip-{temp}.csv"));
        write_recording(&p, &meta, &samples).unwrap();
        let r = read_recording(&p).unwrap();
        assert_eq!(r.meta, meta);
        assert_eq!(r.has_temp, temp);
        assert_eq!(r.samples, samples, "samples differ after write + read");
    }
}

#[test]
fn streaming_writer_flushes_readable_prefix() {
    // The recorder appends and flushes; a reader must see complete rows only.
    let meta = Metadata {
        latitude_deg: Some(39.1),
        ..Default::default()
    };
    let p = scratch("stream.csv");
    let samples = awkward_samples(100, true);
    let mut w = RecordingWriter::create(&p, &meta, true).unwrap();
    for s in &samples[..40] {
        w.write_sample(s).unwrap();
    }
    w.flush().unwrap();
    let r = read_recording(&p).unwrap();
    assert_eq!(r.samples, samples[..40]);
    for s in &samples[40..] {
        w.write_sample(s).unwrap();
    }
    drop(w.into_inner().unwrap());
    assert_eq!(read_recording(&p).unwrap().samples, samples);
}
