//! Unit tests: every error names the file, the line and the reason; round trips are exact.

use super::*;

const HDR: &str = "# latitude_deg: 39.1\n# gravity_mps2: 9.800898\nt_s,ax_mps2,ay_mps2,az_mps2\n";

fn read(bytes: &[u8]) -> Result<Recording, RecordingError> {
    read_recording_from(bytes, "run.csv")
}

/// Asserts the read fails and the message contains every fragment.
fn fails(bytes: &[u8], fragments: &[&str]) -> RecordingError {
    let e = match read(bytes) {
        Ok(r) => panic!("expected an error, read {} samples", r.samples.len()),
        Err(e) => e,
    };
    let msg = e.to_string();
    for f in fragments {
        assert!(msg.contains(f), "message {msg:?} lacks {f:?}");
    }
    e
}

#[test]
fn reads_a_good_file() {
    let text = format!("{HDR}0.0,0.1,0.2,9.8\n1.0,0.1,0.2,9.8\n");
    let r = read(text.as_bytes()).unwrap();
    assert_eq!(r.meta.latitude_deg, Some(39.1));
    assert_eq!(r.meta.gravity_mps2, Some(9.800898));
    assert_eq!(r.samples.len(), 2);
    assert_eq!(r.lines, vec![4, 5]);
    assert!(!r.has_temp);
    assert_eq!(r.samples[1].specific_force_mps2, [0.1, 0.2, 9.8]);
}

#[test]
fn not_a_number_names_line_and_column() {
    let text = format!("{HDR}0.0,0.1,0.2,9.8\n1.0,1.2.3,0.2,9.8\n");
    let e = fails(
        text.as_bytes(),
        &["run.csv:5: column ax_mps2: \"1.2.3\" is not a number"],
    );
    assert_eq!(e.line(), Some(5));
    assert_eq!(e.file(), "run.csv");
}

#[test]
fn missing_column_lists_header() {
    let text = "# latitude_deg: 39.1\n\n# x\nt_s, ax_mps2, ay_mps2\n0,1,2\n";
    fails(
        text.as_bytes(),
        &["run.csv:4: missing required column az_mps2 (header has: t_s, ax_mps2, ay_mps2)"],
    );
}

#[test]
fn duplicate_column() {
    let text = "t_s,ax_mps2,ay_mps2,az_mps2,ax_mps2\n0,1,2,3,4\n";
    fails(
        text.as_bytes(),
        &["run.csv:1:", "ax_mps2 appears twice", "fields 2 and 5"],
    );
}

#[test]
fn time_must_increase() {
    let text = format!("{HDR}11.0,0,0,9.8\n12.0,0,0,9.8\n12.0,0,0,9.8\n");
    fails(
        text.as_bytes(),
        &["run.csv:6: t_s = 12.0 is not after the previous sample's 12.0 (line 5); time must strictly increase"],
    );
    let text = format!("{HDR}11.0,0,0,9.8\n10.0,0,0,9.8\n");
    fails(text.as_bytes(), &["run.csv:5:", "t_s = 10.0", "(line 4)"]);
}

#[test]
fn empty_and_header_only() {
    fails(b"", &["run.csv: no samples (file is empty)"]);
    fails(b"\n\r\n  \n", &["run.csv: no samples (file is empty)"]);
    fails(HDR.as_bytes(), &["run.csv: no samples (header only)"]);
    fails(
        b"# latitude_deg: 10\n# hi\n",
        &["run.csv: no samples (no header row"],
    );
    let text = format!("{HDR}\n\n");
    fails(text.as_bytes(), &["run.csv: no samples (header only)"]);
}

#[test]
fn nan_and_inf_are_kept_for_the_screening() {
    // A sensor's NaN or infinity is a bad sample, not a bad file: it is read (as NaN) and the
    // data-quality screening rejects and counts it (quality::screen).
    for bad in ["NaN", "nan", "inf", "-inf", "Infinity"] {
        let text = format!("{HDR}0.0,0,0,9.8\n1.0,0,{bad},9.8\n2.0,0,0,9.8\n");
        let r = read(text.as_bytes()).unwrap();
        assert_eq!(r.samples.len(), 3);
        assert!(r.samples[1].specific_force_mps2[1].is_nan(), "{bad}");
    }
    // A non-finite time is kept too and does not break the order check of the rows around it.
    let text = format!("{HDR}0.0,0,0,9.8\nNaN,0,0,9.8\n1.0,0,0,9.8\n");
    let r = read(text.as_bytes()).unwrap();
    assert!(r.samples[1].t_s.is_nan());
    // But time still has to increase between finite times.
    let text = format!("{HDR}1.0,0,0,9.8\nNaN,0,0,9.8\n0.5,0,0,9.8\n");
    fails(text.as_bytes(), &["run.csv:6"]);
}

#[test]
fn empty_value_rejected() {
    let text = format!("{HDR}0.0,0,,9.8\n");
    fails(text.as_bytes(), &["run.csv:4: column ay_mps2: empty value"]);
}

#[test]
fn wrong_field_count() {
    let text = format!("{HDR}0.0,0,0,9.8\n1.0,0,0,9.8,7\n2.0,0,0,9.8\n");
    fails(
        text.as_bytes(),
        &["run.csv:5: expected 4 fields (as in the header on line 3), found 5"],
    );
    // Too few fields in a line that does end with a newline: not truncation, a bad row.
    let text = format!("{HDR}0.0,0,0,9.8\n1.0,0,0\n2.0,0,0,9.8\n");
    fails(
        text.as_bytes(),
        &["run.csv:5: expected 4 fields", "found 3"],
    );
}

#[test]
fn non_utf8_reports_line() {
    let mut bytes = format!("{HDR}0.0,0,0,9.8\n").into_bytes();
    bytes.extend_from_slice(b"1.0,0,\xff\xfe,9.8\n");
    fails(&bytes, &["run.csv:5: not valid UTF-8", "0xff", "byte 6"]);
    let mut bytes = b"# description: caf".to_vec();
    bytes.extend_from_slice(b"\xe9\n");
    fails(&bytes, &["run.csv:1: not valid UTF-8"]);
}

#[test]
fn crlf_bom_blank_lines_quotes_and_unknown_columns_accepted() {
    let text = "\u{feff}# latitude_deg: -33.5\r\n# site: lab 2\r\n\"az_mps2\",foo,t_s,ax_mps2,ay_mps2,temp_c\r\n9.8,x,0.0,0.1,0.2,21.5\r\n\r\n9.7,,1.0,0.1,0.2,\r\n\r\n\r\n";
    let r = read(text.as_bytes()).unwrap();
    assert_eq!(r.meta.latitude_deg, Some(-33.5));
    assert_eq!(
        r.meta.extra,
        vec![("site".to_string(), "lab 2".to_string())]
    );
    assert!(r.has_temp);
    assert_eq!(r.samples.len(), 2);
    assert_eq!(r.samples[0].specific_force_mps2, [0.1, 0.2, 9.8]);
    assert_eq!(r.samples[0].temp_c, Some(21.5));
    assert_eq!(r.samples[1].temp_c, None);
    assert_eq!(r.lines, vec![4, 6]);
}

#[test]
fn complete_last_line_without_newline_accepted() {
    let text = format!("{HDR}0.0,0,0,9.8\n1.0,0,0,9.8");
    assert_eq!(read(text.as_bytes()).unwrap().samples.len(), 2);
}

#[test]
fn truncated_last_line_is_dropped_and_reported() {
    let text = format!("{HDR}0.0,0,0,9.8\n1.0,0,0");
    let r = read(text.as_bytes()).unwrap();
    assert_eq!(r.samples.len(), 1);
    assert_eq!(r.repairs.len(), 1);
    assert!(
        r.repairs[0].contains("run.csv:5: truncated last line: 3 of 4 fields and no final newline"),
        "{:?}",
        r.repairs
    );
    // The streaming reader (the recorder's) still reports it as an error item.
    let items: Vec<_> = RecordingReader::new(text.as_bytes(), "run.csv")
        .unwrap()
        .collect();
    assert!(matches!(
        items.last(),
        Some(Err(RecordingError::Truncated { .. }))
    ));
    let text = format!("{HDR}0.0,0,0,9.8\n1.0,0,0,");
    // Four fields, the last empty: the value is missing.
    fails(text.as_bytes(), &["run.csv:5: column az_mps2: empty value"]);
}

#[test]
fn latitude_checked() {
    fails(
        b"# latitude_deg: 95\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n",
        &["run.csv:1: metadata latitude_deg: 95.0 is outside [-90, 90] degrees"],
    );
    fails(
        b"# hello\n# latitude_deg: north\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n",
        &["run.csv:2: metadata latitude_deg: \"north\" is not a number"],
    );
    fails(
        b"# latitude_deg: NaN\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n",
        &["run.csv:1: metadata latitude_deg: NaN is not finite"],
    );
    fails(
        b"# latitude_deg: 10\n# latitude_deg: 11\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n",
        &["run.csv:2: metadata latitude_deg: given twice (first on line 1)"],
    );
    fails(
        b"# gravity_mps2: 1.0\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n",
        &[
            "run.csv:1: metadata gravity_mps2:",
            "not a plausible gravity",
        ],
    );
}

#[test]
fn absurd_magnitude_rejected() {
    let text = format!("{HDR}0.0,0,0,9.8\n1.0,0,0,-1000.5\n");
    fails(
        text.as_bytes(),
        &["run.csv:5: column az_mps2: -1000.5 m/s^2 is implausibly large"],
    );
    let text = "t_s,ax_mps2,ay_mps2,az_mps2,temp_c\n0,0,0,9.8,5000\n";
    fails(
        text.as_bytes(),
        &["run.csv:2: column temp_c: 5000.0", "plausible range"],
    );
}

#[test]
fn comment_lines_that_look_like_text_are_not_metadata() {
    let text = "# Recorded with rig 3: cold start\n# latitude_deg: 1\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n";
    let r = read(text.as_bytes()).unwrap();
    assert!(r.meta.extra.is_empty());
    assert_eq!(r.meta.latitude_deg, Some(1.0));
}

#[test]
fn never_panics_on_junk() {
    // A crude fuzz: deterministic pseudo-random bytes drawn from a CSV-ish alphabet.
    let alphabet = b"0123456789.,-+eE#:\n\r \xff\xc3naiftsxyz_mp2";
    let mut state = 0x9e3779b97f4a7c15u64;
    for len in 0..400usize {
        let mut bytes = Vec::with_capacity(len);
        for _ in 0..len {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            bytes.push(alphabet[(state % alphabet.len() as u64) as usize]);
        }
        let mut with_hdr = HDR.as_bytes().to_vec();
        with_hdr.extend_from_slice(&bytes);
        for b in [&bytes, &with_hdr] {
            if let Err(e) = read(b) {
                assert!(e.to_string().starts_with("run.csv"));
            }
        }
    }
}

#[test]
fn streaming_reader_stops_after_error() {
    let text = format!("{HDR}0.0,0,0,9.8\n1.0,x,0,9.8\n2.0,0,0,9.8\n");
    let r = RecordingReader::new(text.as_bytes(), "run.csv").unwrap();
    let items: Vec<_> = r.collect();
    assert_eq!(items.len(), 2);
    assert!(items[0].is_ok());
    assert!(items[1].is_err());
}

#[test]
fn round_trip_in_memory_is_exact() {
    let meta = Metadata {
        latitude_deg: Some(39.1),
        gravity_mps2: Some(9.800_898_123_456_7),
        description: Some("two\nlines".into()),
        extra: vec![("k".into(), "v".into())],
    };
    let samples: Vec<RawSample> = (0..50)
        .map(|i| {
            let x = i as f64;
            RawSample {
                t_s: x * 0.1 + 1e-13 * x,
                specific_force_mps2: [(x * 1.234567).sin() * 1e-3, 1.0 / 3.0 + x, -9.8 - 1e-17 * x],
                temp_c: if i % 7 == 3 {
                    None
                } else {
                    Some(20.0 + x / 3.0)
                },
            }
        })
        .collect();
    let mut w = RecordingWriter::new(Vec::new(), &meta, true).unwrap();
    for s in &samples {
        w.write_sample(s).unwrap();
    }
    assert_eq!(w.rows_written(), 50);
    let bytes = w.into_inner().unwrap();
    let r = read(&bytes).unwrap();
    assert_eq!(r.samples, samples);
    assert_eq!(r.meta.latitude_deg, meta.latitude_deg);
    assert_eq!(r.meta.gravity_mps2, meta.gravity_mps2);
    assert_eq!(r.meta.description.as_deref(), Some("two lines"));
    assert_eq!(r.meta.extra, meta.extra);
}

#[test]
fn writer_refuses_what_the_reader_would_reject() {
    let mut w = RecordingWriter::new(Vec::new(), &Metadata::default(), false).unwrap();
    let s = RawSample {
        t_s: 1.0,
        specific_force_mps2: [0.0, 0.0, 9.8],
        temp_c: None,
    };
    w.write_sample(&s).unwrap();
    assert!(w.write_sample(&s).is_err());
    let bad = RawSample {
        t_s: 2.0,
        specific_force_mps2: [f64::NAN, 0.0, 9.8],
        temp_c: None,
    };
    assert!(w.write_sample(&bad).is_err());
}

/// A line longer than MAX_LINE_BYTES stops the reader at that line, naming file, line and limit;
/// a line of exactly the limit (CRLF or not) is still read.
#[test]
fn a_line_beyond_the_cap_is_an_error_naming_line_and_limit() {
    // A data row padded with spaces inside a field up to exactly the cap: accepted.
    let row = "2.0,0.1,0.2,9.8";
    let pad = " ".repeat(MAX_LINE_BYTES - row.len());
    for ending in ["\n", "\r\n"] {
        let text = format!("{HDR}1.0,0.1,0.2,9.8\n2.0,0.1,0.2,{pad}9.8{ending}");
        let r = read(text.as_bytes()).unwrap();
        assert_eq!(r.samples.len(), 2, "a line of exactly the cap is fine");
    }
    // One byte more: refused.
    let text = format!("{HDR}1.0,0.1,0.2,9.8\n2.0,0.1,0.2, {pad}9.8\n");
    let e = fails(
        text.as_bytes(),
        &["run.csv:5:", &MAX_LINE_BYTES.to_string()],
    );
    assert!(
        matches!(e, RecordingError::LineTooLong { line: 5, .. }),
        "{e:?}"
    );
    // A "file" with no line break at all: refused on line 1, without reading all of it.
    let big = vec![b'x'; 4 * MAX_LINE_BYTES];
    let e = fails(&big, &["run.csv:1:", "longer than"]);
    assert!(e.to_string().len() < 200, "short message: {e}");
}

/// Errors quote at most a short prefix of the file's text.
#[test]
fn errors_quote_only_a_short_prefix_of_bad_text() {
    let long = "z".repeat(10_000);
    let text = format!("{HDR}0.0,{long},0.2,9.8\n");
    let e = fails(
        text.as_bytes(),
        &["run.csv:4:", "ax_mps2", "10000 bytes in all"],
    );
    assert!(e.to_string().len() < 300, "{} bytes", e.to_string().len());
    let text = format!("# latitude_deg: 39.1\nt_s,{long}\n");
    let e = fails(text.as_bytes(), &["run.csv:2:", "missing required column"]);
    assert!(e.to_string().len() < 300, "{} bytes", e.to_string().len());
    let text = format!("# latitude_deg: {long}\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n");
    let e = fails(text.as_bytes(), &["run.csv:1:", "latitude_deg"]);
    assert!(e.to_string().len() < 300, "{} bytes", e.to_string().len());
    assert_eq!(excerpt("short"), "short");
    let cut = excerpt(&"é".repeat(100));
    assert!(cut.starts_with(&"é".repeat(ERROR_EXCERPT_CHARS)) && cut.contains("200 bytes"));
}

/// The writer refuses what the reader would refuse, so a written file always reads back.
#[test]
fn the_writer_refuses_what_the_reader_refuses() {
    let meta = Metadata {
        latitude_deg: Some(120.0),
        ..Metadata::default()
    };
    assert!(RecordingWriter::new(Vec::new(), &meta, false).is_err());
    let meta = Metadata {
        gravity_mps2: Some(f64::NAN),
        ..Metadata::default()
    };
    assert!(RecordingWriter::new(Vec::new(), &meta, false).is_err());
    let mut w = RecordingWriter::new(Vec::new(), &Metadata::default(), true).unwrap();
    let s = |t: f64, a: f64, temp: Option<f64>| RawSample {
        t_s: t,
        specific_force_mps2: [0.0, a, 9.8],
        temp_c: temp,
    };
    assert!(
        w.write_sample(&s(0.0, 2000.0, None)).is_err(),
        "|a| > limit"
    );
    assert!(
        w.write_sample(&s(0.0, 0.0, Some(5000.0))).is_err(),
        "temperature"
    );
    assert!(w.write_sample(&s(f64::NAN, 0.0, None)).is_err(), "NaN time");
    w.write_sample(&s(0.0, 0.0, Some(20.0))).unwrap();
    assert!(
        w.write_sample(&s(0.0, 0.0, None)).is_err(),
        "time not increasing"
    );
    let bytes = w.into_inner().unwrap();
    assert_eq!(read(&bytes).unwrap().samples.len(), 1);
}

/// The reader's fast path (fast-float2) and its general path (`str::parse`) must accept the same
/// number text and give the same bits: compared over pseudo-random strings of number characters.
#[test]
fn fast_float_parsing_agrees_with_std() {
    let alphabet = b"0123456789.+-eE";
    let mut state = 0x2545f4914f6cdd1du64;
    let mut accepted = 0;
    for i in 0..200_000usize {
        let len = 1 + i % 14;
        let mut text = String::with_capacity(len);
        for _ in 0..len {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            text.push(alphabet[(state % alphabet.len() as u64) as usize] as char);
        }
        let std = text.parse::<f64>().ok().filter(|v| v.is_finite());
        let fast = match fast_float2::parse_partial::<f64, _>(&text) {
            Ok((v, used)) if used == text.len() && v.is_finite() => Some(v),
            _ => None,
        };
        assert_eq!(
            std.map(f64::to_bits),
            fast.map(f64::to_bits),
            "{text:?}: std {std:?}, fast-float2 {fast:?}"
        );
        accepted += usize::from(std.is_some());
    }
    assert!(accepted > 10_000, "too few valid numbers drawn: {accepted}");
}

/// A reader with a 1-byte buffer never sees a whole line at once, so it takes the general path
/// only; with a large buffer nearly every row takes the fast path. Both must read the same
/// samples and lines, and fail with the same message.
#[test]
fn fast_and_general_paths_agree() {
    let mut state = 0x9e3779b97f4a7c15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let forms = ["{}", "{:e}", "{:.3}", "{:.17e}"];
    let mut text = String::from("# latitude_deg: 39.1\nfoo,t_s,ax_mps2,ay_mps2,az_mps2,temp_c\n");
    for i in 0..3000 {
        let v = |r: u64| (r % 2_000_001) as f64 * 1e-4 - 100.0;
        let fmt = |x: f64, k: u64| match forms[(k % 4) as usize] {
            "{}" => format!("{x}"),
            "{:e}" => format!("{x:e}"),
            "{:.3}" => format!("{x:.3}"),
            _ => format!("{x:.17e}"),
        };
        let (a, b, c, k) = (next(), next(), next(), next());
        let temp = if k % 5 == 0 {
            String::new()
        } else {
            fmt(v(k) * 0.1, k >> 8)
        };
        let ending = if k % 7 == 0 { "\r\n" } else { "\n" };
        text.push_str(&format!(
            "x{i},{},{},{},{},{temp}{ending}",
            fmt(i as f64 * 0.5, k >> 3),
            fmt(v(a), k >> 5),
            fmt(v(b), k >> 9),
            fmt(v(c) + 9.8, k >> 11),
        ));
        if k % 97 == 0 {
            text.push_str("# a comment\n\n");
        }
        if k % 89 == 0 {
            text.push_str(&format!(
                "\"x\",{}, 0.5 ,\"0.25\",9.8,\n",
                i as f64 * 0.5 + 0.25
            ));
        }
    }
    let slow =
        |bytes: &[u8]| read_recording_from(std::io::BufReader::with_capacity(1, bytes), "run.csv");
    let fast = |bytes: &[u8]| read_recording_from(bytes, "run.csv");
    let (s, f) = (
        slow(text.as_bytes()).unwrap(),
        fast(text.as_bytes()).unwrap(),
    );
    assert_eq!(s.samples.len(), f.samples.len());
    assert!(s.samples.len() > 3000);
    for (x, y) in s.samples.iter().zip(&f.samples) {
        assert_eq!(format!("{x:?}"), format!("{y:?}"));
    }
    assert_eq!(s.lines, f.lines);
    // Errors: each defect put after some good rows reads the same way on both paths.
    let defects = [
        "1e9,0,0,9.8,",
        "nan,0,0,9.8,",
        "1.0,inf,0,9.8,",
        "5,0,0,2000,",
        "5,0,0,9.8,2000",
        "0.0,0,0,9.8,",
        "6,0,0,9.8",
        "6,0,0,9.8,1,2",
        "6,x,0,9.8,",
        "6,,0,9.8,",
        "6,0,0,9.8,1e",
        "6,0,0,\u{e9},",
        "6,0,0,9.8,-",
    ];
    for d in defects {
        let text = format!("# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2,temp_c\n1,0,0,9.8,\n2,0,0,9.8,20\n{d}\n7,0,0,9.8,\n");
        let show = |r: Result<Recording, RecordingError>| match r {
            Ok(r) => format!("{:?} {:?}", r.samples, r.lines),
            Err(e) => e.to_string(),
        };
        assert_eq!(
            show(slow(text.as_bytes())),
            show(fast(text.as_bytes())),
            "{d:?}"
        );
    }
}

/// The block reader's result is the one-thread reader's: the same samples, lines and repairs,
/// or the same error on the same line, whatever the blocks. Rows of every kind (CRLF, blank,
/// comments, quoted fields, NaN kept for the screening) and each defect at five places land at
/// the seams of blocks of 40 to 4096 bytes read by 2 to 4 threads, from a stream and from bytes
/// in memory (as a mapped file is read); a line longer than the cap and more than a block leaves
/// the rest to the one-thread reader.
#[test]
fn blocks_read_as_one_thread_reads() {
    let mut rows: Vec<Vec<u8>> = Vec::new();
    for k in 0..400 {
        let t = k as f64 * 0.5;
        let row = match k % 9 {
            0 => format!("{t},0.1,-0.2,9.8\r\n"),
            1 => "\n".to_string(),
            2 => "# a comment, with commas, é\n".to_string(),
            3 => format!("\"{t}\", 0.25 ,-0.125,9.75\n"),
            4 => format!("{t},NaN,0.0,9.8\n"),
            _ => format!(
                "{t},{:.9},{:.9},9.80{}\n",
                k as f64 * 1e-4,
                -(k as f64) * 2e-5,
                k % 10
            ),
        };
        rows.push(row.into_bytes());
    }
    let long = format!("1e8,{}0,0,9.8\n", " ".repeat(MAX_LINE_BYTES)).into_bytes();
    let defects: Vec<Vec<u8>> = vec![
        b"1.0e9x,0,0,9.8\n".to_vec(),
        b"-5,0,0,9.8\n".to_vec(),
        b"1e8,0,0\n".to_vec(),
        b"\xff\xfe,0,0,9.8\n".to_vec(),
        b"NaN,0,0,9.8\n".to_vec(),
        b"1e8,,0,9.8\n".to_vec(),
        b"1e8,2000,0,9.8\n".to_vec(),
        long,
    ];
    let mut cases = vec![rows.concat()];
    for at in [0, 1, 57, 200, 399] {
        for d in &defects {
            let mut r = rows.clone();
            r[at] = d.clone();
            cases.push(r.concat());
        }
        // A repeated time (the row before, when it is a data row).
        let mut r = rows.clone();
        r[at] = rows[at.saturating_sub(1)].clone();
        cases.push(r.concat());
    }
    let mut truncated = rows.concat();
    truncated.extend_from_slice(b"1e9,0,0");
    cases.push(truncated);
    for body in cases {
        let text = [HDR.as_bytes(), &body].concat();
        let one = read(&text);
        for threads in [2, 3, 4] {
            for block in [40, 64, 300, 4096] {
                let reader = RecordingReader::new(&text[..], "run.csv");
                let many = reader.and_then(|r| {
                    collect(r, Path::new("run.csv"), 0, |r, rows| {
                        blocks::read_rows_parallel(r, rows, threads, block)
                    })
                });
                match (&one, &many) {
                    // Compared as text: NaN values (kept for the screening) are not equal
                    // to themselves.
                    (Ok(a), Ok(b)) => assert!(
                        format!("{a:?}") == format!("{b:?}"),
                        "{threads} threads, blocks of {block}: {} and {} samples, repairs {:?} and {:?}",
                        a.samples.len(),
                        b.samples.len(),
                        a.repairs,
                        b.repairs
                    ),
                    (Err(a), Err(b)) => assert_eq!(
                        a.to_string(),
                        b.to_string(),
                        "{threads} threads, blocks of {block}"
                    ),
                    _ => panic!(
                        "{threads} threads, blocks of {block}: one thread {:?}, blocks {:?}",
                        one.as_ref().map(|r| r.samples.len()),
                        many.as_ref().map(|r| r.samples.len())
                    ),
                }
            }
        }
    }
}

/// What a test does to the file at `AFTER_HEADER`.
type FileHook = Box<dyn Fn(&Path)>;

thread_local! {
    /// Run by [`read_recording`] once the header is read, on the reading thread: a test plays
    /// the other program that changes the file while it is read.
    pub(super) static AFTER_HEADER: std::cell::RefCell<Option<FileHook>> =
        const { std::cell::RefCell::new(None) };
}

/// A recording of `rows` rows at 1 s, in `dir/name`.
fn write_rows(dir: &Path, name: &str, rows: usize) -> PathBuf {
    use std::fmt::Write as _;
    let mut text = String::from(HDR);
    for k in 0..rows {
        writeln!(text, "{k},0.000123,-0.000456,9.800898").unwrap();
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// A file cut short by another program while it is read (issue 28, item 9): the reader names
/// the truncation and both lengths, not the rows it happened to get (before, a cut within a row
/// was "repaired" as a recorder's truncated last line and the rest trusted; a mapped file cut
/// while its pages were read killed the process with SIGBUS). Over 2 MiB: the block reader's
/// path on a machine of several cores, the one-thread path otherwise; both are checked by the
/// cut at a row's middle and at a row's end. Fails if the check after reading is lost, or reads
/// beyond the length at opening are trusted.
#[test]
fn a_file_shortened_while_read_is_named() {
    let dir = std::env::temp_dir().join(format!("driftid-shrink-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = write_rows(&dir, "run.csv", 80_000);
    let full = std::fs::metadata(&path).unwrap().len();
    for cut in [full / 2, full - 1] {
        let path = write_rows(&dir, "run.csv", 80_000);
        AFTER_HEADER.with(|h| {
            *h.borrow_mut() = Some(Box::new(move |p: &Path| {
                let f = std::fs::OpenOptions::new().write(true).open(p).unwrap();
                f.set_len(cut).unwrap();
            }))
        });
        let got = read_recording(&path);
        AFTER_HEADER.with(|h| *h.borrow_mut() = None);
        match got {
            Err(RecordingError::Shrank {
                opened_bytes,
                now_bytes,
                ..
            }) => assert_eq!((opened_bytes, now_bytes), (full, cut)),
            other => panic!(
                "cut to {cut} of {full} bytes: {:?}",
                other.map(|r| r.repairs)
            ),
        }
    }
    // A file that grows while it is read (a recorder appending) is read to its length at
    // opening, as before: no error, the rows of then.
    AFTER_HEADER.with(|h| {
        *h.borrow_mut() = Some(Box::new(|p: &Path| {
            use std::io::Write as _;
            let mut f = std::fs::OpenOptions::new().append(true).open(p).unwrap();
            f.write_all(b"90000,0,0,9.8\n").unwrap();
        }))
    });
    let path = write_rows(&dir, "run.csv", 80_000);
    let got = read_recording(&path);
    AFTER_HEADER.with(|h| *h.borrow_mut() = None);
    assert_eq!(got.unwrap().samples.len(), 80_000);
    let _ = std::fs::remove_dir_all(&dir);
}
