//! Fuzzing the effects-file compiler on stable (proptest, part of every `cargo test`; issue 28:
//! effect files are code a user hands the tool). The seeds are the committed corpus
//! `tests/fuzz-corpus/effects/*.toml`; each case mutates one (bytes deleted, tokens of the
//! expression language and of TOML inserted, lines duplicated or swapped, numbers replaced by
//! extremes, the text cut). A second target builds random expression trees, deeper and longer
//! than the limits. Properties: never a panic or a stack overflow (the test threads have 2 MiB
//! of stack, less than the CLI's main thread); every refusal names the file and, unless it is
//! about the whole file, the line and column; every accepted effect, evaluated anywhere, either
//! gives finite values or records a numeric failure naming the file, line, effect and expression.
//! The CSV reader and the frame decoder have their own targets (host-tool/tests/fuzz_recording.rs,
//! protocol/tests/fuzz.rs).

use std::path::{Path, PathBuf};

use estimator_core::effects::{Context, Effect, Partials};
use host_tool::effects_file::{parse_effects, UserEffect, MAX_EXPR_CHARS, MAX_EXPR_DEPTH};
use nalgebra::{Matrix3, Vector3};
use proptest::prelude::*;

const NAME: &str = "fuzz.toml";

fn corpus() -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz-corpus/effects");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 4, "corpus missing in {}", dir.display());
    files
        .iter()
        .map(|p| std::fs::read_to_string(p).unwrap())
        .collect()
}

const TOKENS: [&str; 34] = [
    "sin(",
    "cos(",
    "abs(",
    "sqrt(",
    "ln(",
    "exp(",
    "(",
    ")",
    "^",
    "*",
    "/",
    "-",
    "+",
    "1e308",
    "0",
    "A_x",
    "up_y",
    "t_h",
    "temp_c",
    "__s0",
    "K2x",
    "[[effect]]\n",
    "\"",
    "=",
    "\n",
    "[",
    "]",
    "{",
    "}",
    ",",
    "name = \"x\"\n",
    "params = []\n",
    "é",
    "\u{0}",
];
const NUMBERS: [&str; 8] = [
    "1e308", "-1", "0", "1e-320", "nan", "inf", "1e31", "\"big\"",
];

#[derive(Clone, Debug)]
enum Edit {
    Delete(usize, usize),
    Insert(usize, usize),
    DuplicateLine(usize),
    SwapLines(usize, usize),
    Number(usize, usize),
    Truncate(usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<usize>(), 1usize..20).prop_map(|(a, n)| Edit::Delete(a, n)),
        (any::<usize>(), any::<usize>()).prop_map(|(a, t)| Edit::Insert(a, t)),
        any::<usize>().prop_map(Edit::DuplicateLine),
        (any::<usize>(), any::<usize>()).prop_map(|(a, b)| Edit::SwapLines(a, b)),
        (any::<usize>(), any::<usize>()).prop_map(|(a, t)| Edit::Number(a, t)),
        any::<usize>().prop_map(Edit::Truncate),
    ]
}

/// The largest char boundary ≤ `a % (len + 1)`.
fn boundary(s: &str, a: usize) -> usize {
    let mut i = a % (s.len() + 1);
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

fn apply(seed: &str, edits: &[Edit]) -> String {
    let mut s = seed.to_string();
    for e in edits {
        match e {
            Edit::Delete(a, n) => {
                let i = boundary(&s, *a);
                let j = boundary(&s, (i + n).min(s.len()));
                s.replace_range(i..j.max(i), "");
            }
            Edit::Insert(a, t) => s.insert_str(boundary(&s, *a), TOKENS[t % TOKENS.len()]),
            Edit::DuplicateLine(a) | Edit::SwapLines(a, _) => {
                let mut lines: Vec<&str> = s.split_inclusive('\n').collect();
                if lines.is_empty() {
                    continue;
                }
                let i = a % lines.len();
                match e {
                    Edit::SwapLines(_, b) => {
                        let j = b % lines.len();
                        lines.swap(i, j);
                    }
                    _ => lines.insert(i, lines[i]),
                }
                s = lines.concat();
            }
            Edit::Number(a, t) => {
                // Replace the first number at or after the position (a prior, a constant).
                let i = boundary(&s, *a);
                if let Some(k) = s[i..].find(|c: char| c.is_ascii_digit()) {
                    let k = i + k;
                    let end = s[k..]
                        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '.' || c == '-'))
                        .map_or(s.len(), |e| k + e);
                    s.replace_range(k..end, NUMBERS[t % NUMBERS.len()]);
                }
            }
            Edit::Truncate(a) => {
                let i = boundary(&s, *a);
                s.truncate(i);
            }
        }
    }
    s
}

/// A refusal names the file, and the line and column unless it is about the whole file.
fn assert_located(msg: &str) -> Result<(), TestCaseError> {
    prop_assert!(msg.starts_with(NAME), "refusal without the file: {msg}");
    let rest = &msg[NAME.len()..];
    let whole_file = rest.starts_with(": no effects");
    let mut parts = rest.splitn(4, ':');
    let (_, line, col) = (parts.next(), parts.next(), parts.next());
    let is_num =
        |p: Option<&str>| p.is_some_and(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
    prop_assert!(
        whole_file || (is_num(line) && is_num(col)),
        "refusal without line:column: {msg}"
    );
    Ok(())
}

/// Contexts spanning what a run shows an effect: every direction of a ~g specific force, zero
/// and opposite signs, the first instant and late ones, temperature swings.
fn contexts() -> Vec<Context> {
    let forces = [
        [0.0, 0.0, 9.8],
        [-9.8, 0.0, 0.0],
        [3.1, -5.2, 7.3],
        [0.0, 0.0, 0.0],
        [-6.5, 4.4, -5.6],
    ];
    forces
        .iter()
        .enumerate()
        .map(|(n, f)| Context {
            t_s: 3600.0 * 15.0 * n as f64,
            specific_force: Vector3::from(*f),
            temp_dev_c: -3.0 + 1.5 * n as f64,
            north: Vector3::new(0.6, 0.8, 0.0),
        })
        .collect()
}

/// Evaluates an accepted effect everywhere; a non-finite value or derivative must have been
/// recorded as a located numeric failure naming the effect.
fn check_evaluation(e: &UserEffect) -> Result<(), TestCaseError> {
    let n = e.params().len();
    let mut finite = true;
    for ctx in contexts() {
        for scale in [0.0, 1.0, -1e3] {
            let p: Vec<f64> = (0..n).map(|k| scale * e.params()[k].prior_sigma).collect();
            let mut cols = vec![Vector3::zeros(); n];
            let (mut value, mut d_force) = (Vector3::zeros(), Matrix3::zeros());
            let out = Partials {
                value: &mut value,
                d_params: &mut cols,
                d_force: &mut d_force,
            };
            if e.touches_drift() {
                e.drift(&p, &ctx, out);
            } else {
                e.accel_error(&p, &ctx, out);
            }
            finite &= value.iter().chain(d_force.iter()).all(|v| v.is_finite());
            finite &= cols.iter().flat_map(|c| c.iter()).all(|v| v.is_finite());
        }
    }
    match e.numeric_failure() {
        Some(m) => {
            assert_located(m)?;
            prop_assert!(m.contains(&format!("effect `{}`", e.name())), "{m}");
        }
        None => prop_assert!(finite, "non-finite value not recorded for `{}`", e.name()),
    }
    Ok(())
}

/// A random expression: nested function calls and sums, `depth` levels of parentheses at most.
fn expression() -> impl Strategy<Value = String> {
    let leaf = prop_oneof![
        Just("K".to_string()),
        Just("A_x".to_string()),
        Just("up_z".to_string()),
        Just("t_h".to_string()),
        Just("2.5e-3".to_string()),
    ];
    leaf.prop_recursive(24, 400, 3, |inner| {
        prop_oneof![
            (0usize..7, inner.clone()).prop_map(|(f, e)| {
                let f = ["sin", "cos", "abs", "sqrt", "ln", "exp", ""][f];
                format!("{f}({e})")
            }),
            (inner.clone(), 0usize..4, inner)
                .prop_map(|(a, o, b)| { format!("{a}{}K*{b}", ["+", "-", "*", "/"][o]) }),
        ]
    })
}

fn depth(s: &str) -> usize {
    let (mut d, mut m) = (0usize, 0usize);
    for c in s.chars() {
        match c {
            '(' => {
                d += 1;
                m = m.max(d);
            }
            ')' => d = d.saturating_sub(1),
            _ => {}
        }
    }
    m
}

proptest! {
    // Bounded for CI: the whole file runs in about a second on one core (measured); the cases
    // still reach every edit kind on every seed many times.
    #![proptest_config(ProptestConfig { cases: 600, ..ProptestConfig::default() })]

    #[test]
    fn mutated_effect_files_give_located_refusals_or_sound_effects(
        seed in any::<usize>(),
        edits in proptest::collection::vec(edit(), 0..6),
    ) {
        let seeds = corpus();
        let text = apply(&seeds[seed % seeds.len()], &edits);
        match parse_effects(Path::new(NAME), &text) {
            Ok(effects) => {
                for e in &effects {
                    check_evaluation(e)?;
                }
            }
            Err(e) => assert_located(&format!("{e:#}"))?,
        }
    }

    #[test]
    fn random_expressions_compile_or_are_refused_by_a_limit(x in expression()) {
        let file = format!(
            "[[effect]]\nname = \"r\"\napplies_to = \"drift\"\nparams = [ {{ name = \"K\", prior_sigma = 1e-3 }} ]\nx = \"{x}\"\ny = \"K * A_y\"\nz = \"0\"\n"
        );
        let over = x.chars().count() > MAX_EXPR_CHARS || depth(&x) > MAX_EXPR_DEPTH;
        match parse_effects(Path::new(NAME), &file) {
            Ok(effects) => {
                prop_assert!(!over, "accepted beyond the limits: {} chars, depth {}", x.len(), depth(&x));
                check_evaluation(&effects[0])?;
            }
            Err(e) => {
                let msg = format!("{e:#}");
                assert_located(&msg)?;
                prop_assert!(msg.starts_with("fuzz.toml:5:5: effect `r`: x = "), "{msg}");
                if over {
                    prop_assert!(msg.contains("at most"), "{msg}");
                }
            }
        }
    }
}
