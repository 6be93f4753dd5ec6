//! Fuzzing the recording reader on stable (proptest): a valid recording mutated line by line
//! (delete, duplicate, swap, truncate, CRLF) and byte by byte (random bytes including non-UTF-8,
//! numbers replaced by NaN/Inf/huge/garbage, fields added or removed). Properties: never a panic;
//! every error names the file, and a line number when it concerns a line; every accepted
//! recording holds only finite values with strictly increasing time — the reader either says
//! what is wrong and where, or gives numbers that can be trusted.

use proptest::prelude::*;

const NAME: &str = "fuzz.csv";

fn valid() -> Vec<String> {
    let mut lines = vec![
        "# latitude_deg: 39.1".to_string(),
        "# description: fuzz base".into(),
        "t_s,ax_mps2,ay_mps2,az_mps2,temp_c".into(),
    ];
    for k in 0..40 {
        let t = k as f64;
        lines.push(format!(
            "{t:?},{:?},{:?},{:?},{:?}",
            1e-3 * t.sin(),
            -2e-3 * t.cos(),
            9.8 + 1e-6 * t,
            20.0 + 0.01 * t
        ));
    }
    lines
}

#[derive(Clone, Debug)]
enum Edit {
    DeleteLine(usize),
    DuplicateLine(usize),
    SwapLines(usize, usize),
    ReplaceField(usize, usize, u8),
    AddField(usize),
    RemoveField(usize),
    InsertBytes(usize, Vec<u8>),
    Truncate(usize),
    Crlf,
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        any::<usize>().prop_map(Edit::DeleteLine),
        any::<usize>().prop_map(Edit::DuplicateLine),
        (any::<usize>(), any::<usize>()).prop_map(|(a, b)| Edit::SwapLines(a, b)),
        (any::<usize>(), any::<usize>(), 0u8..8).prop_map(|(a, b, c)| Edit::ReplaceField(a, b, c)),
        any::<usize>().prop_map(Edit::AddField),
        any::<usize>().prop_map(Edit::RemoveField),
        (any::<usize>(), proptest::collection::vec(any::<u8>(), 1..6))
            .prop_map(|(a, b)| Edit::InsertBytes(a, b)),
        any::<usize>().prop_map(Edit::Truncate),
        Just(Edit::Crlf),
    ]
}

const REPLACEMENTS: [&str; 8] = ["NaN", "inf", "-inf", "1e300", "", "abc", "1.2.3", "-0"];

fn apply(edits: &[Edit]) -> Vec<u8> {
    let mut lines = valid();
    let mut crlf = false;
    let mut byte_edits = vec![];
    let mut truncate = None;
    for e in edits {
        let n = lines.len().max(1);
        match e {
            Edit::DeleteLine(i) => {
                if !lines.is_empty() {
                    lines.remove(i % n);
                }
            }
            Edit::DuplicateLine(i) => {
                if !lines.is_empty() {
                    let l = lines[i % n].clone();
                    lines.insert(i % n, l);
                }
            }
            Edit::SwapLines(a, b) => {
                if !lines.is_empty() {
                    lines.swap(a % n, b % n);
                }
            }
            Edit::ReplaceField(i, f, r) => {
                if !lines.is_empty() {
                    let mut fs: Vec<String> = lines[i % n].split(',').map(String::from).collect();
                    let k = f % fs.len();
                    fs[k] = REPLACEMENTS[*r as usize].to_string();
                    lines[i % n] = fs.join(",");
                }
            }
            Edit::AddField(i) => {
                if !lines.is_empty() {
                    lines[i % n].push_str(",7");
                }
            }
            Edit::RemoveField(i) => {
                if !lines.is_empty() {
                    if let Some(p) = lines[i % n].rfind(',') {
                        lines[i % n].truncate(p);
                    }
                }
            }
            Edit::InsertBytes(a, b) => byte_edits.push((*a, b.clone())),
            Edit::Truncate(a) => truncate = Some(*a),
            Edit::Crlf => crlf = !crlf,
        }
    }
    let nl = if crlf { "\r\n" } else { "\n" };
    let mut bytes: Vec<u8> = lines
        .iter()
        .flat_map(|l| format!("{l}{nl}").into_bytes())
        .collect();
    for (a, b) in byte_edits {
        let at = a % (bytes.len() + 1);
        bytes.splice(at..at, b);
    }
    if let Some(a) = truncate {
        bytes.truncate(a % (bytes.len() + 1));
    }
    bytes
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, ..ProptestConfig::default() })]

    #[test]
    fn mutated_recordings_give_located_errors_or_trustworthy_samples(edits in proptest::collection::vec(edit(), 0..6)) {
        let bytes = apply(&edits);
        match host_tool::recording::read_recording_from(std::io::Cursor::new(&bytes), NAME) {
            Ok(rec) => {
                prop_assert!(!rec.samples.is_empty());
                // Finite times increase strictly; a non-finite time or value is kept as NaN for
                // the data-quality screening to reject and count (never a wrong number).
                let mut prev = f64::NEG_INFINITY;
                for s in &rec.samples {
                    if s.t_s.is_finite() {
                        prop_assert!(s.t_s > prev, "time {} after {}", s.t_s, prev);
                        prev = s.t_s;
                    } else {
                        prop_assert!(s.t_s.is_nan(), "time {}", s.t_s);
                    }
                    prop_assert!(s.specific_force_mps2.iter().all(|v| v.is_nan() || (v.is_finite() && v.abs() < 1000.0)));
                    prop_assert!(s.temp_c.is_none_or(|t| t.is_finite()));
                }
                for r in &rec.repairs {
                    prop_assert!(r.starts_with(&format!("{NAME}:")), "repair without a line: {}", r);
                }
            }
            Err(e) => {
                let msg = e.to_string();
                prop_assert!(msg.starts_with(NAME), "error without the file: {}", msg);
                // Whole-file complaints (empty, no samples, no latitude) need no line; the rest do.
                let whole_file = msg.contains("no samples") || msg.contains("no `# latitude_deg") || msg.contains("is empty");
                let located = msg[NAME.len()..].starts_with(':') && msg[NAME.len() + 1..].chars().next().is_some_and(|c| c.is_ascii_digit());
                prop_assert!(whole_file || located, "error without a line: {}", msg);
            }
        }
    }

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..3000)) {
        match host_tool::recording::read_recording_from(std::io::Cursor::new(&bytes), NAME) {
            Ok(rec) => prop_assert!(rec.samples.iter().all(|s| s.t_s.is_finite() || s.t_s.is_nan())),
            Err(e) => prop_assert!(e.to_string().starts_with(NAME)),
        }
    }
}
