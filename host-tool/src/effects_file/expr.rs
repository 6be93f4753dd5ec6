//! One axis expression of a file effect: checked against the limits, parsed with exmex, its
//! derived variables (`up_x`, …) and `abs` rewritten into what exmex differentiates, and its
//! symbolic partial derivatives taken once.

use estimator_core::effects::Context;
use estimator_core::units::S_PER_H;
use exmex::prelude::*;
use exmex::MatchLiteral; // named by literal_matcher_from_pattern!

/// Longest expression accepted, characters. exmex's differentiation grows faster than linearly
/// with the expression (a 20 000-term expression took over 300 s; 49 parameters in three
/// 773-character sums, 32 s); see also [`MAX_DERIVATIVE_WORK`].
pub const MAX_EXPR_CHARS: usize = 300;
/// Deepest nesting of parentheses accepted: exmex parses and differentiates recursively (300
/// nested `sin(` overflowed the stack, exit 134) and each level multiplies the derivative's
/// size; 8 levels is beyond any physical formula.
pub const MAX_EXPR_DEPTH: usize = 8;
/// Most differentiation work of one effect: Σ over its three expressions of (variables
/// differentiated: parameters, A and north components)² × (characters once `up_*`, `east_*`
/// and `abs` are rewritten). exmex's time per derivative grows with the expression's length and its number of
/// variables (~5 µs per unit of this measure, from 2 to 49 variables and 80 to 300
/// characters), so the costliest effect admitted compiles in about a second (49 parameters in
/// one 225-character sum took 2.7 s).
pub(crate) const MAX_DERIVATIVE_WORK: usize = 200_000;

/// The variables every expression may use besides the effect's parameters, with their meaning.
pub(crate) const VARIABLES: [(&str, &str); 14] = [
    ("A_x", "specific force along platform x, m/s^2"),
    ("A_y", "specific force along platform y, m/s^2"),
    ("A_z", "specific force along platform z, m/s^2"),
    (
        "up_x",
        "platform-x component of the local vertical (up, unit vector, A/|A|)",
    ),
    (
        "up_y",
        "platform-y component of the local vertical (up, unit vector, A/|A|)",
    ),
    (
        "up_z",
        "platform-z component of the local vertical (up, unit vector, A/|A|)",
    ),
    (
        "north_x",
        "platform-x component of local north (unit vector)",
    ),
    (
        "north_y",
        "platform-y component of local north (unit vector)",
    ),
    (
        "north_z",
        "platform-z component of local north (unit vector)",
    ),
    (
        "east_x",
        "platform-x component of local east (unit vector, north x up)",
    ),
    (
        "east_y",
        "platform-y component of local east (unit vector, north x up)",
    ),
    (
        "east_z",
        "platform-z component of local east (unit vector, north x up)",
    ),
    ("t_h", "hours since the start of the run"),
    (
        "temp_c",
        "platform temperature minus its value at the first measurement, deg C",
    ),
];

/// Derived variables, replaced by their definition before parsing (in this order: east uses up)
/// so that exmex differentiates them through the specific force and north (their ∂/∂A and
/// ∂/∂north then reach the attitude chain like A's). East is north × up: frame 0 is ENU
/// (x east, y north, z up, right-handed), and a rotation keeps cross products.
const DERIVED: [(&str, &str); 6] = [
    ("east_x", "(north_y*up_z-north_z*up_y)"),
    ("east_y", "(north_z*up_x-north_x*up_z)"),
    ("east_z", "(north_x*up_y-north_y*up_x)"),
    ("up_x", "(A_x/sqrt(A_x^2+A_y^2+A_z^2))"),
    ("up_y", "(A_y/sqrt(A_x^2+A_y^2+A_z^2))"),
    ("up_z", "(A_z/sqrt(A_x^2+A_y^2+A_z^2))"),
];

/// Prefix of the hidden variables holding the sign of an `abs` argument (refused as a user name).
pub(crate) const HIDDEN_PREFIX: &str = "__";

// exmex's default number literal has no exponent (`1e-6` would not parse): numbers here are
// decimal literals with an optional exponent, read by `f64::from_str`.
exmex::literal_matcher_from_pattern!(
    SciNumber,
    r"^([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?"
);

/// A compiled expression: f64, exmex's float operators, numbers with exponents.
pub(crate) type Expr = FlatEx<f64, exmex::FloatOpsFactory<f64>, SciNumber>;

/// Parses an expression (no checks; see [`compile`]).
pub(crate) fn parse_expr(s: &str) -> exmex::ExResult<Expr> {
    Expr::parse(s)
}

/// What one variable of a compiled expression is bound to.
#[derive(Clone, Copy, Debug)]
enum Slot {
    Force(usize),
    /// Component `j` of local north in platform axes ([`Context::north`]).
    North(usize),
    TimeH,
    TempC,
    Param(usize),
    /// The `k`-th recording column the effect declares (`columns = [...]`).
    Column(usize),
    /// The sign of the `k`-th `abs` argument (a constant for differentiation: d|u| = sign(u)·du).
    Sign(usize),
}

/// An expression with the binding of each of its variables (`var_names()` order).
#[derive(Debug)]
struct Bound {
    expr: Expr,
    slots: Vec<Slot>,
}

/// Most expressions have a handful of variables: evaluate them without allocating.
pub(crate) type Vars = smallvec::SmallVec<[f64; 12]>;

impl Bound {
    fn bind(&self, p: &[f64], ctx: &Context, cols: &[f64], signs: &[f64]) -> Vars {
        self.slots
            .iter()
            .map(|s| match *s {
                Slot::Force(j) => ctx.specific_force[j],
                Slot::North(j) => ctx.north[j],
                Slot::TimeH => ctx.t_s / S_PER_H,
                Slot::TempC => ctx.temp_dev_c,
                Slot::Param(k) => p[k],
                Slot::Column(k) => cols[k],
                Slot::Sign(k) => signs[k],
            })
            .collect()
    }
}

/// Evaluates a compiled expression. The variable count is fixed at load time, so exmex cannot
/// fail here; should it ever, the value is NaN, which the effect reports (see `UserEffect`).
pub(crate) fn eval(e: &Expr, vars: &[f64]) -> f64 {
    e.eval(vars).unwrap_or(f64::NAN)
}

/// One axis: the expression, its variable bindings and its symbolic partial derivatives.
#[derive(Debug)]
pub(crate) struct AxisExpr {
    /// The expression as written (for messages).
    pub source: String,
    value: Bound,
    /// The arguments of the `abs` calls, innermost first (each may use the earlier signs).
    abs_args: Vec<Bound>,
    /// ∂/∂parameter k, for the parameters the expression uses.
    pub d_params: Vec<(usize, Expr)>,
    /// ∂/∂A_j, for the force components the expression uses.
    pub d_force: Vec<(usize, Expr)>,
    /// ∂/∂north_j, for the north components the expression uses (east and up included).
    pub d_north: Vec<(usize, Expr)>,
}

impl AxisExpr {
    /// The values of the value's (and its derivatives') variables at parameters `p`, `cols`
    /// the values of the effect's recording columns at this instant.
    pub(crate) fn bind(&self, p: &[f64], ctx: &Context, cols: &[f64]) -> Vars {
        let mut signs: smallvec::SmallVec<[f64; 4]> = smallvec::SmallVec::new();
        for a in &self.abs_args {
            let u = eval(&a.expr, &a.bind(p, ctx, cols, &signs));
            signs.push(if u < 0.0 {
                -1.0
            } else if u >= 0.0 {
                1.0
            } else {
                u
            });
        }
        self.value.bind(p, ctx, cols, &signs)
    }
    /// Whether the expression reads local north (`north_*`, or `east_*` through it).
    pub(crate) fn uses_north(&self) -> bool {
        self.value.slots.iter().any(|s| matches!(s, Slot::North(_)))
    }
    /// The value for variables from [`AxisExpr::bind`].
    pub(crate) fn value(&self, vars: &[f64]) -> f64 {
        eval(&self.value.expr, vars)
    }
}

/// Why an expression is refused (the caller adds file, line and effect).
pub(crate) type Refusal = String;

/// The expression shortened for a message (a refused expression may be megabytes long).
pub(crate) fn excerpt(src: &str) -> String {
    const SHOWN: usize = 60;
    if src.chars().count() <= SHOWN {
        src.to_string()
    } else {
        let head: String = src.chars().take(SHOWN).collect();
        format!("{head}… ({} characters)", src.chars().count())
    }
}

/// The checked limits, before exmex sees the text.
fn check_limits(src: &str) -> Result<(), Refusal> {
    let n = src.chars().count();
    if n > MAX_EXPR_CHARS {
        return Err(format!(
            "expression of {n} characters; at most {MAX_EXPR_CHARS} are accepted (split the effect, or factor the expression)"
        ));
    }
    let (mut depth, mut deepest) = (0usize, 0usize);
    for c in src.chars() {
        match c {
            '(' => {
                depth += 1;
                deepest = deepest.max(depth);
            }
            ')' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    if deepest > MAX_EXPR_DEPTH {
        return Err(format!(
            "parentheses nested {deepest} deep; at most {MAX_EXPR_DEPTH} levels are accepted"
        ));
    }
    Ok(())
}

fn is_ident_char(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Byte ranges of the whole-word occurrences of `word` in `s`.
fn word_ranges(s: &str, word: &str) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(i) = s[from..].find(word) {
        let (a, b) = (from + i, from + i + word.len());
        let before = s[..a].chars().next_back().is_none_or(|c| !is_ident_char(c));
        let after = s[b..].chars().next().is_none_or(|c| !is_ident_char(c));
        if before && after {
            out.push(a..b);
        }
        from = b;
    }
    out
}

/// Character position (1-based) of the first whole-word occurrence of `word` in `expr`.
pub(crate) fn word_position(expr: &str, word: &str) -> Option<usize> {
    word_ranges(expr, word)
        .first()
        .map(|r| expr[..r.start].chars().count() + 1)
}

/// `s` with every whole-word `word` replaced by `with`.
fn replace_word(s: &str, word: &str, with: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut last = 0;
    for r in word_ranges(s, word) {
        out.push_str(&s[last..r.start]);
        out.push_str(with);
        last = r.end;
    }
    out.push_str(&s[last..]);
    out
}

/// Rewrites the derived variables and every `abs(u)` as `((u)*__sK)`, `__sK` the sign of `u`
/// (exmex has no derivative of `abs`). Returns the text and the `abs` arguments, innermost
/// first: the last `abs(` of the text contains no other, so rewriting from the end leaves each
/// argument with only the signs found before it.
fn rewrite(src: &str) -> (String, Vec<String>) {
    let mut s = src.to_string();
    for (word, with) in DERIVED {
        s = replace_word(&s, word, with);
    }
    let mut args = Vec::new();
    while let Some(r) = word_ranges(&s, "abs").into_iter().rev().find_map(|r| {
        let open = r.end + s[r.end..].len() - s[r.end..].trim_start().len();
        s[open..].starts_with('(').then_some((r.start, open))
    }) {
        let (start, open) = r;
        let mut depth = 0usize;
        let close = s[open..].char_indices().find_map(|(i, c)| {
            match c {
                '(' => depth += 1,
                ')' => depth -= 1,
                _ => {}
            }
            (depth == 0).then_some(open + i)
        });
        let Some(close) = close else { break }; // unbalanced: exmex refused it already
        let inner = s[open + 1..close].to_string();
        let sign = format!("{HIDDEN_PREFIX}s{}", args.len());
        s = format!("{}(({inner})*{sign}){}", &s[..start], &s[close + 1..]);
        args.push(inner);
    }
    (s, args)
}

/// Binds the variables of a parsed (rewritten) expression; an unknown one is refused.
fn bind_vars(expr: Expr, params: &[&str], columns: &[&str]) -> Result<Bound, String> {
    let mut slots = Vec::new();
    for v in expr.var_names() {
        let slot = match v.as_str() {
            "A_x" => Slot::Force(0),
            "A_y" => Slot::Force(1),
            "A_z" => Slot::Force(2),
            "north_x" => Slot::North(0),
            "north_y" => Slot::North(1),
            "north_z" => Slot::North(2),
            "t_h" => Slot::TimeH,
            "temp_c" => Slot::TempC,
            _ => match params.iter().position(|p| p == v) {
                Some(k) => Slot::Param(k),
                None if columns.contains(&v.as_str()) => {
                    Slot::Column(columns.iter().position(|c| c == v).unwrap_or(0))
                }
                None => match v
                    .strip_prefix(HIDDEN_PREFIX)
                    .and_then(|k| k.strip_prefix('s'))
                {
                    Some(k) => Slot::Sign(k.parse().map_err(|_| v.clone())?),
                    None => return Err(v.clone()),
                },
            },
        };
        slots.push(slot);
    }
    Ok(Bound { expr, slots })
}

/// Stack of the thread that compiles an expression. exmex parses and differentiates
/// recursively, one level per operator of a chain (`a+b+c+…`), not only per parenthesis: the
/// largest expression the limits admit overflowed a test thread's 2 MiB. Only the pages used are
/// committed, so a generous reservation costs nothing.
const COMPILE_STACK_BYTES: usize = 256 << 20;

/// Parses, checks and differentiates one expression; `params` are the effect's parameter
/// names, `columns` the recording columns it declares. A refusal says what is wrong with the
/// expression (the caller names file and place). Runs on a thread of its own with
/// [`COMPILE_STACK_BYTES`] of stack, whatever the caller's.
pub(crate) fn compile(
    src: &str,
    params: &[&str],
    columns: &[&str],
    budget: usize,
) -> Result<(AxisExpr, usize), Refusal> {
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("effects-file compiler".into())
            .stack_size(COMPILE_STACK_BYTES)
            .spawn_scoped(scope, || compile_here(src, params, columns, budget))
            .map_err(|e| format!("cannot start the expression compiler: {e}"))?
            .join()
            .map_err(|_| "the expression compiler failed (a bug: please report it)".to_string())?
    })
}

/// [`compile`] on the caller's thread; also returns the differentiation work it spent of
/// `budget` (see [`MAX_DERIVATIVE_WORK`]).
fn compile_here(
    src: &str,
    params: &[&str],
    columns: &[&str],
    budget: usize,
) -> Result<(AxisExpr, usize), Refusal> {
    if src.trim().is_empty() {
        return Err(
            "empty expression (write \"0\" for an axis the effect does not touch)".to_string(),
        );
    }
    check_limits(src)?;
    let original = parse_expr(src).map_err(|e| format!("not a valid expression: {}", e.msg()))?;
    known_variables_only(src, &original, params, columns)?;
    let (text, abs_texts) = rewrite(src);
    let internal = |e: String| format!("cannot compile the expression (variable `{e}`)");
    let parse = |t: &str| parse_expr(t).map_err(|e| format!("not a valid expression: {}", e.msg()));
    let value = bind_vars(parse(&text)?, params, columns).map_err(internal)?;
    let mut abs_args = Vec::new();
    for t in &abs_texts {
        abs_args.push(bind_vars(parse(t)?, params, columns).map_err(internal)?);
    }
    let n_diff = value
        .slots
        .iter()
        .filter(|s| matches!(s, Slot::Param(_) | Slot::Force(_) | Slot::North(_)))
        .count();
    let work = n_diff * n_diff * text.chars().count();
    if work > budget {
        return Err(format!(
            "too costly to differentiate: ({n_diff} variables)² × {} characters = {work} (once \
             up_* and abs are rewritten), but the effect's three expressions may \
             spend at most {MAX_DERIVATIVE_WORK} together ({} left); use fewer parameters per \
             expression (split the effect) or shorter expressions",
            text.chars().count(),
            budget
        ));
    }
    let (d_params, d_force, d_north) = derivatives(&value)?;
    let ax = AxisExpr {
        source: src.to_string(),
        value,
        abs_args,
        d_params,
        d_force,
        d_north,
    };
    Ok((ax, work))
}

/// Refuses a variable of `original` (parsed from `src`) that is neither a built-in one, one of
/// the effect's `params` nor one of its declared recording `columns`, naming where it is and
/// what may be used.
fn known_variables_only(
    src: &str,
    original: &Expr,
    params: &[&str],
    columns: &[&str],
) -> Result<(), Refusal> {
    for v in original.var_names() {
        let known = VARIABLES.iter().any(|(n, _)| n == v)
            || params.contains(&v.as_str())
            || columns.contains(&v.as_str());
        if !known {
            let at = word_position(src, v)
                .map(|c| format!(" (character {c} of the expression)"))
                .unwrap_or_default();
            let vars: Vec<&str> = VARIABLES.iter().map(|(n, _)| *n).collect();
            let cols = if columns.is_empty() {
                String::new()
            } else {
                format!(", its recording columns {}", columns.join(", "))
            };
            return Err(format!(
                "unknown variable `{v}`{at}; an expression may use {}, the effect's \
                 parameters {}{cols} (a recording column must be declared: columns = [\"{v}\"])",
                vars.join(", "),
                params.join(", ")
            ));
        }
    }
    Ok(())
}

/// Partial derivatives, each with the index of the parameter or component it is taken for.
type Partials = Vec<(usize, Expr)>;

/// The derivatives of `value` the filter needs, symbolic: with respect to each parameter, force
/// component and north component it uses (∂/∂parameter k, ∂/∂A_j, ∂/∂north_j, in slot order).
fn derivatives(value: &Bound) -> Result<(Partials, Partials, Partials), Refusal> {
    let (mut d_params, mut d_force, mut d_north) = (Vec::new(), Vec::new(), Vec::new());
    for (idx, slot) in value.slots.iter().enumerate() {
        let d = || {
            value.expr.clone().partial(idx).map_err(|e| {
                format!(
                    "cannot differentiate with respect to `{}`: {}",
                    value.expr.var_names()[idx],
                    e.msg()
                )
            })
        };
        match *slot {
            Slot::Param(k) => d_params.push((k, d()?)),
            Slot::Force(j) => d_force.push((j, d()?)),
            Slot::North(j) => d_north.push((j, d()?)),
            Slot::TimeH | Slot::TempC | Slot::Column(_) | Slot::Sign(_) => {}
        }
    }
    Ok((d_params, d_force, d_north))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx(a: [f64; 3]) -> Context {
        Context {
            t_s: 7200.0,
            specific_force: nalgebra::Vector3::from(a),
            temp_dev_c: 0.5,
            north: nalgebra::Vector3::new(0.8, -0.6, 0.0),
        }
    }

    /// `abs` evaluates to |u| and its derivative to sign(u)·du, nested too; exact in f64 for
    /// these small integers and halves, so the comparisons are exact.
    #[test]
    fn abs_and_its_derivative() {
        let e = compile(
            "K * abs(A_x - 2*abs(A_y))",
            &["K"],
            &[],
            MAX_DERIVATIVE_WORK,
        )
        .unwrap()
        .0;
        for (a, value, dk) in [
            ([1.0, 3.0, 0.0], 3.0 * 5.0, 5.0),  // |1 - 6| = 5
            ([7.0, -3.0, 0.0], 3.0 * 1.0, 1.0), // |7 - 6| = 1
            ([-1.0, 0.5, 0.0], 3.0 * 2.0, 2.0), // |-1 - 1| = 2
        ] {
            let vars = e.bind(&[3.0], &ctx(a), &[]);
            assert_eq!(e.value(&vars), value, "{a:?}");
            assert_eq!(eval(&e.d_params[0].1, &vars), dk, "{a:?}");
        }
        // ∂/∂A_x of K·|A_x − 2|A_y|| at A = (1, 3): K·sign(−5) = −3; ∂/∂A_y: K·(−1)(−2)·sign(3) = 6.
        let vars = e.bind(&[3.0], &ctx([1.0, 3.0, 0.0]), &[]);
        let d: Vec<(usize, f64)> = e
            .d_force
            .iter()
            .map(|(j, d)| (*j, eval(d, &vars)))
            .collect();
        assert!(d.contains(&(0, -3.0)) && d.contains(&(1, 6.0)), "{d:?}");
    }

    /// `up_x` is A_x/|A|, with ∂/∂A_x = (|A|² − A_x²)/|A|³; 3-4-12 gives |A| = 13 exactly, the
    /// tolerance is a few ulps of the divisions.
    #[test]
    fn up_is_the_unit_specific_force() {
        let e = compile("K * up_x", &["K"], &[], MAX_DERIVATIVE_WORK)
            .unwrap()
            .0;
        let vars = e.bind(&[2.0], &ctx([3.0, 4.0, 12.0]), &[]);
        assert!((e.value(&vars) - 2.0 * 3.0 / 13.0).abs() < 1e-15);
        let (_, d) = e.d_force.iter().find(|(j, _)| *j == 0).unwrap();
        assert!((eval(d, &vars) - 2.0 * (169.0 - 9.0) / 2197.0).abs() < 1e-15);
    }

    /// The limits are checked before exmex sees the text (the differentiation budget before
    /// the derivatives are taken).
    #[test]
    fn limits_are_refused_with_the_limit() {
        let w = MAX_DERIVATIVE_WORK;
        let deep = format!("{}K{}", "sin(".repeat(9), ")".repeat(9));
        let e = compile(&deep, &["K"], &[], w).unwrap_err();
        assert!(
            e.contains("nested 9 deep") && e.contains("at most 8"),
            "{e}"
        );
        let eight = format!("{}K{}", "sin(".repeat(8), ")".repeat(8));
        assert!(compile(&eight, &["K"], &[], w).is_ok());
        let long = vec!["K*A_x"; 4000].join("+");
        let e = compile(&long, &["K"], &[], w).unwrap_err();
        assert!(
            e.contains("23999 characters") && e.contains("at most 300"),
            "{e}"
        );
        assert!(excerpt(&long).ends_with("(23999 characters)"));
        // 40 parameters in a 149-character sum: 40² × 149 = 238 400, over the budget.
        let names: Vec<String> = (0..40).map(|i| format!("P{i}")).collect();
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let e = compile(&refs.join("+"), &refs, &[], w).unwrap_err();
        let head = "too costly to differentiate: (40 variables)² × 149 characters = 238400";
        assert!(e.starts_with(head), "{e}");
        // 30 of them (109 characters): 30² × 109 = 98 100 spent.
        let refs = &refs[..30];
        assert_eq!(compile(&refs.join("+"), refs, &[], w).unwrap().1, 98_100);
    }
}
