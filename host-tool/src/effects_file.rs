//! Effects defined by the user in a TOML file, without Rust (`--effects FILE.toml`).
//!
//! ```toml
//! [[effect]]
//! name = "acc-k2"
//! about = "Second-order accelerometer nonlinearity"
//! applies_to = "accelerometer"   # or "drift"
//! params = [ { name = "K2x", unit = "1/(m/s^2)", prior_sigma = 1e-5 },
//!            { name = "K2y", unit = "1/(m/s^2)", prior_sigma = 1e-5 },
//!            { name = "K2z", unit = "1/(m/s^2)", prior_sigma = 1e-5 } ]
//! x = "K2x * A_x^2"
//! y = "K2y * A_y^2"
//! z = "K2z * A_z^2"
//! ```
//!
//! Each axis expression is parsed once with [`exmex`] and differentiated symbolically, once per
//! parameter and once per specific-force component, at load time; the resulting [`UserEffect`]
//! implements [`Effect`] like a built-in effect (value, ∂/∂params, ∂/∂A), so the model chains its
//! partials into the analytic F and H exactly as for Rust effects.
//!
//! Variables an expression may use (see [`VARIABLES`]):
//! - `A_x`, `A_y`, `A_z`: the true specific force along the platform axes, m/s² (the model's
//!   `Context::specific_force`, `A = C·g0`);
//! - `t_h`: hours since the start of the run (θ = 0), `Context::t_s / 3600`;
//! - `temp_c`: the platform temperature's *deviation from its value at the first measurement*,
//!   °C (`Context::temp_dev_c`; 0 when the recording has no `temp_c` column). A constant
//!   temperature offset is indistinguishable from the constant drift, so only the deviation is
//!   offered, as for the built-in `temp-drift`;
//! - the effect's own parameters, by name.
//!
//! Extra recording columns are not available yet: the core's `Context` does not carry them, and
//! naming one is an error at load time (never silently zero).
//!
//! An accelerometer effect adds its value (m/s²) to that axis' accelerometer output; a drift
//! effect adds its value (deg/h) to that gyro's drift rate. Parameters are constants (no
//! Gauss–Markov dynamics).

use std::fmt::Write as _;
use std::ops::Range;
use std::path::{Path, PathBuf};

use estimator_core::effects::{Context, Effect, Param, Partials};
use estimator_core::units::S_PER_H;
use exmex::prelude::*;
use exmex::MatchLiteral; // named by literal_matcher_from_pattern!
use serde::Deserialize;
use toml::Spanned;

use crate::cli::common::ModelArgs;

/// The variables every expression may use besides the effect's parameters, with their meaning.
pub const VARIABLES: [(&str, &str); 5] = [
    ("A_x", "specific force along platform x, m/s^2"),
    ("A_y", "specific force along platform y, m/s^2"),
    ("A_z", "specific force along platform z, m/s^2"),
    ("t_h", "hours since the start of the run"),
    (
        "temp_c",
        "platform temperature minus its value at the first measurement, deg C",
    ),
];

const AXES: [&str; 3] = ["x", "y", "z"];

/// Where an effect adds its value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AppliesTo {
    /// Accelerometer output, m/s².
    Accelerometer,
    /// Gyro drift rate, deg/h.
    Drift,
}

/// What one variable of a compiled expression is bound to.
#[derive(Clone, Copy, Debug)]
enum Slot {
    Force(usize),
    TimeH,
    TempC,
    Param(usize),
}

/// One axis: the expression, its variable bindings and its symbolic partial derivatives.
#[derive(Debug)]
struct AxisExpr {
    /// The expression as written (for messages).
    source: String,
    value: Expr,
    /// Binding of each of `value.var_names()` (the derivatives keep the same variable list).
    slots: Vec<Slot>,
    /// ∂/∂parameter k, for the parameters the expression uses.
    d_params: Vec<(usize, Expr)>,
    /// ∂/∂A_j, for the force components the expression uses.
    d_force: Vec<(usize, Expr)>,
}

// exmex's default number literal has no exponent (`1e-6` would not parse): numbers here are
// decimal literals with an optional exponent, read by `f64::from_str`.
exmex::literal_matcher_from_pattern!(
    SciNumber,
    r"^([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?"
);

/// A compiled expression: f64, exmex's float operators, numbers with exponents.
type Expr = FlatEx<f64, exmex::FloatOpsFactory<f64>, SciNumber>;

fn parse_expr(s: &str) -> exmex::ExResult<Expr> {
    Expr::parse(s)
}

/// Most expressions have a handful of variables: evaluate them without allocating.
type Vars = smallvec::SmallVec<[f64; 12]>;

impl AxisExpr {
    fn bind(&self, p: &[f64], ctx: &Context) -> Vars {
        self.slots
            .iter()
            .map(|s| match *s {
                Slot::Force(j) => ctx.specific_force[j],
                Slot::TimeH => ctx.t_s / S_PER_H,
                Slot::TempC => ctx.temp_dev_c,
                Slot::Param(k) => p[k],
            })
            .collect()
    }
}

/// Evaluates a compiled expression. The variable count is fixed at load time, so exmex cannot
/// fail here; should it ever, the value is NaN, which the filter's checks report with the step.
fn eval(e: &Expr, vars: &[f64]) -> f64 {
    e.eval(vars).unwrap_or(f64::NAN)
}

/// An effect read from a TOML file. Its strings are leaked once per run (see `leak`); the
/// registered effect itself is leaked by [`load_and_register`].
#[derive(Debug)]
pub struct UserEffect {
    name: &'static str,
    about: &'static str,
    applies_to: AppliesTo,
    params: Vec<Param>,
    axes: [AxisExpr; 3],
    /// The file it came from (for messages).
    file: PathBuf,
}

impl UserEffect {
    /// Where the effect adds its value.
    pub fn applies_to(&self) -> AppliesTo {
        self.applies_to
    }
    /// The file the effect was defined in.
    pub fn file(&self) -> &Path {
        &self.file
    }
    /// The expression of axis `i` (0 = x) as written in the file.
    pub fn expression(&self, i: usize) -> &str {
        &self.axes[i].source
    }

    fn contribute(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        for d in out.d_params.iter_mut() {
            *d = nalgebra::Vector3::zeros();
        }
        for (i, ax) in self.axes.iter().enumerate() {
            let vars = ax.bind(p, ctx);
            out.value[i] += eval(&ax.value, &vars);
            for (k, d) in &ax.d_params {
                out.d_params[*k][i] = eval(d, &vars);
            }
            for (j, d) in &ax.d_force {
                out.d_force[(i, *j)] += eval(d, &vars);
            }
        }
    }
}

impl Effect for UserEffect {
    fn name(&self) -> &'static str {
        self.name
    }
    fn about(&self) -> &'static str {
        self.about
    }
    fn params(&self) -> &[Param] {
        &self.params
    }
    fn drift(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        if self.applies_to == AppliesTo::Drift {
            self.contribute(p, ctx, out);
        }
    }
    fn accel_error(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        if self.applies_to == AppliesTo::Accelerometer {
            self.contribute(p, ctx, out);
        }
    }
    fn touches_drift(&self) -> bool {
        self.applies_to == AppliesTo::Drift
    }
    fn touches_accel(&self) -> bool {
        self.applies_to == AppliesTo::Accelerometer
    }
}

// ---------------------------------------------------------------------------------------------
// The file format.

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileDef {
    #[serde(default)]
    effect: Vec<Spanned<EffectDef>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EffectDef {
    name: Option<Spanned<String>>,
    about: Option<String>,
    applies_to: Option<Spanned<String>>,
    params: Option<Spanned<Vec<Spanned<ParamDef>>>>,
    x: Option<Spanned<String>>,
    y: Option<Spanned<String>>,
    z: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ParamDef {
    name: Spanned<String>,
    #[serde(default)]
    unit: String,
    prior_sigma: Spanned<f64>,
}

/// 1-based line and column of byte `offset` in `src` (column counted in characters).
fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(src.len());
    let before = &src[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before
        .rfind('\n')
        .map_or(before, |n| &before[n + 1..])
        .chars()
        .count()
        + 1;
    (line, col)
}

/// The `[[effect]]` table containing byte `offset`, for a TOML error inside it: its header line
/// and, if it can be read off the text, its name.
fn enclosing_effect(src: &str, offset: usize) -> Option<(usize, Option<String>)> {
    let mut found = None;
    let mut pos = 0;
    for (n, line) in src.split_inclusive('\n').enumerate() {
        if pos > offset {
            break;
        }
        let t = line.trim();
        if t.starts_with("[[")
            && t.trim_start_matches("[[")
                .trim_start()
                .starts_with("effect")
        {
            found = Some((n + 1, None));
        } else if t.starts_with('[') {
            found = None;
        } else if let Some((_, name)) = found.as_mut() {
            if name.is_none() {
                if let Some(rest) = t.strip_prefix("name") {
                    if let Some(v) = rest.trim_start().strip_prefix('=') {
                        let v = v.trim();
                        if let Some(v) = v.strip_prefix('"').and_then(|v| v.split('"').next()) {
                            *name = Some(v.to_string());
                        }
                    }
                }
            }
        }
        pos += line.len();
    }
    found
}

/// Builds located error messages for one file.
struct Loc<'a> {
    file: &'a Path,
    src: &'a str,
}

impl Loc<'_> {
    fn at(&self, span: Range<usize>) -> String {
        let (l, c) = line_col(self.src, span.start);
        format!("{}:{l}:{c}", self.file.display())
    }
    fn err(&self, span: Range<usize>, effect: &str, msg: impl std::fmt::Display) -> anyhow::Error {
        anyhow::anyhow!("{}: effect `{effect}`: {msg}", self.at(span))
    }
}

fn is_identifier(s: &str) -> bool {
    let mut ch = s.chars();
    matches!(ch.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && ch.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// Character position (1-based) of the first whole-word occurrence of `word` in `expr`.
fn word_position(expr: &str, word: &str) -> Option<usize> {
    let is_id = |c: char| c.is_alphanumeric() || c == '_';
    let mut from = 0;
    while let Some(i) = expr[from..].find(word) {
        let s = from + i;
        let e = s + word.len();
        let ok_before = expr[..s].chars().next_back().is_none_or(|c| !is_id(c));
        let ok_after = expr[e..].chars().next().is_none_or(|c| !is_id(c));
        if ok_before && ok_after {
            return Some(expr[..s].chars().count() + 1);
        }
        from = e;
    }
    None
}

/// Leaks a string for the `&'static str` the [`Effect`] trait asks for. Acceptable on the host:
/// a run loads each user file once, and the few names it leaks live as long as the process
/// anyway (the catalog is static).
fn leak(s: &str) -> &'static str {
    Box::leak(s.to_owned().into_boxed_str())
}

/// Parses and checks one expression; `params` are the effect's parameter names.
fn compile(
    loc: &Loc<'_>,
    effect: &str,
    axis: &str,
    expr: &Spanned<String>,
    params: &[&str],
) -> anyhow::Result<AxisExpr> {
    let src = expr.get_ref();
    let span = expr.span();
    let what = format!("{axis} = \"{src}\"");
    if src.trim().is_empty() {
        return Err(loc.err(
            span,
            effect,
            format!("{what}: empty expression (write \"0\" for an axis the effect does not touch)"),
        ));
    }
    let value = parse_expr(src).map_err(|e| {
        loc.err(
            span.clone(),
            effect,
            format!("{what}: not a valid expression: {}", e.msg()),
        )
    })?;
    let mut slots = Vec::new();
    for v in value.var_names() {
        let slot = match v.as_str() {
            "A_x" => Slot::Force(0),
            "A_y" => Slot::Force(1),
            "A_z" => Slot::Force(2),
            "t_h" => Slot::TimeH,
            "temp_c" => Slot::TempC,
            _ => match params.iter().position(|p| p == v) {
                Some(k) => Slot::Param(k),
                None => {
                    let at = word_position(src, v)
                        .map(|c| format!(" (character {c} of the expression)"))
                        .unwrap_or_default();
                    let known: Vec<&str> = VARIABLES.iter().map(|(n, _)| *n).collect();
                    return Err(loc.err(
                        span,
                        effect,
                        format!(
                            "{what}: unknown variable `{v}`{at}; an expression may use {} and the \
                             effect's parameters {} (extra recording columns are not supported yet)",
                            known.join(", "),
                            params.join(", ")
                        ),
                    ));
                }
            },
        };
        slots.push(slot);
    }
    let mut d_params = Vec::new();
    let mut d_force = Vec::new();
    for (idx, slot) in slots.iter().enumerate() {
        let d = || {
            value.clone().partial(idx).map_err(|e| {
                loc.err(
                    span.clone(),
                    effect,
                    format!(
                        "{what}: cannot differentiate with respect to `{}`: {}",
                        value.var_names()[idx],
                        e.msg()
                    ),
                )
            })
        };
        match *slot {
            Slot::Param(k) => d_params.push((k, d()?)),
            Slot::Force(j) => d_force.push((j, d()?)),
            Slot::TimeH | Slot::TempC => {}
        }
    }
    Ok(AxisExpr {
        source: src.clone(),
        value,
        slots,
        d_params,
        d_force,
    })
}

/// A few instants at which a parameter's partial derivative is probed: if it is zero at all of
/// them the parameter does not enter the effect and cannot be identified.
fn probe_contexts() -> Vec<Context> {
    let forces = [
        [3.1, -5.2, 7.3],
        [-6.5, 4.4, 5.6],
        [0.7, 9.1, -3.3],
        [9.8, 0.2, -0.4],
    ];
    forces
        .iter()
        .enumerate()
        .map(|(n, f)| Context {
            t_s: 3600.0 * (1.7 + 13.0 * n as f64),
            specific_force: nalgebra::Vector3::from(*f),
            temp_dev_c: -2.3 + 1.9 * n as f64,
        })
        .collect()
}

/// Builds one effect from its table; `span` locates the table.
fn build_effect(
    loc: &Loc<'_>,
    span: Range<usize>,
    def: &EffectDef,
    index: usize,
) -> anyhow::Result<UserEffect> {
    let Some(name) = &def.name else {
        return Err(anyhow::anyhow!(
            "{}: effect #{} has no `name`",
            loc.at(span),
            index + 1
        ));
    };
    let n = name.get_ref().as_str();
    if n.is_empty()
        || !n
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        return Err(loc.err(
            name.span(),
            n,
            "the name must be non-empty and use only letters, digits, `-` and `_` (it is typed after --with)",
        ));
    }
    let applies_to = match def.applies_to.as_ref() {
        None => return Err(loc.err(span, n, "no `applies_to` (\"accelerometer\" or \"drift\")")),
        Some(a) => match a.get_ref().as_str() {
            "accelerometer" => AppliesTo::Accelerometer,
            "drift" => AppliesTo::Drift,
            other => {
                return Err(loc.err(
                    a.span(),
                    n,
                    format!("applies_to = \"{other}\": must be \"accelerometer\" or \"drift\""),
                ))
            }
        },
    };
    let Some(params) = def.params.as_ref().filter(|p| !p.get_ref().is_empty()) else {
        let at = def.params.as_ref().map_or(span.clone(), |p| p.span());
        return Err(loc.err(
            at,
            n,
            "no parameters: give `params = [ { name = …, unit = …, prior_sigma = … }, … ]`",
        ));
    };
    let mut names: Vec<&str> = Vec::new();
    let mut out_params = Vec::new();
    for p in params.get_ref() {
        let pd = p.get_ref();
        let pn = pd.name.get_ref().as_str();
        if !is_identifier(pn) {
            return Err(loc.err(
                pd.name.span(),
                n,
                format!("parameter name `{pn}`: must be a letter or `_` followed by letters, digits or `_`"),
            ));
        }
        if VARIABLES.iter().any(|(v, _)| *v == pn) {
            return Err(loc.err(
                pd.name.span(),
                n,
                format!("parameter name `{pn}` is a reserved variable"),
            ));
        }
        // exmex reads some names as operators or constants (`sin`, `E`, `PI`, …).
        let as_var = parse_expr(pn)
            .map(|e| e.var_names() == [pn.to_string()])
            .unwrap_or(false);
        if !as_var {
            return Err(loc.err(
                pd.name.span(),
                n,
                format!(
                    "parameter name `{pn}` is a function or constant of the expression language"
                ),
            ));
        }
        if names.contains(&pn) {
            return Err(loc.err(pd.name.span(), n, format!("parameter `{pn}` given twice")));
        }
        let s = *pd.prior_sigma.get_ref();
        if !(s.is_finite() && s > 0.0) {
            return Err(loc.err(
                pd.prior_sigma.span(),
                n,
                format!("parameter `{pn}`: prior_sigma = {s} must be a finite positive number"),
            ));
        }
        names.push(pn);
        out_params.push((pn, pd.unit.as_str(), s));
    }
    let mut axes = Vec::with_capacity(3);
    for (i, e) in [&def.x, &def.y, &def.z].into_iter().enumerate() {
        let Some(e) = e else {
            return Err(loc.err(
                span,
                n,
                format!(
                    "no `{}` expression (all of x, y and z are required; write \"0\" for an axis the effect does not touch)",
                    AXES[i]
                ),
            ));
        };
        axes.push(compile(loc, n, AXES[i], e, &names)?);
    }
    let axes: [AxisExpr; 3] = axes.try_into().expect("three axes");
    // Every parameter must move the value somewhere, or it cannot be identified.
    let probes = probe_contexts();
    for (k, pn) in names.iter().enumerate() {
        let p_probe: Vec<f64> = (0..names.len()).map(|m| 0.37 + 0.11 * m as f64).collect();
        let moves = axes.iter().any(|ax| {
            ax.d_params.iter().any(|(kk, d)| {
                *kk == k
                    && probes.iter().any(|ctx| {
                        let v = eval(d, &ax.bind(&p_probe, ctx));
                        v != 0.0 && !v.is_nan()
                    })
            })
        });
        if !moves {
            let mut msg = format!("parameter `{pn}` ");
            if axes
                .iter()
                .any(|ax| ax.d_params.iter().any(|(kk, _)| *kk == k))
            {
                msg.push_str("has a zero partial derivative everywhere we probed it");
            } else {
                msg.push_str("appears in none of x, y, z");
            }
            let _ = write!(
                msg,
                ": it does not change the effect's value, so it cannot be identified"
            );
            let pspan = params.get_ref()[k].get_ref().name.span();
            return Err(loc.err(pspan, n, msg));
        }
    }
    let about = def
        .about
        .clone()
        .unwrap_or_else(|| format!("User-defined effect from {}.", loc.file.display()));
    Ok(UserEffect {
        name: leak(n),
        about: leak(&about),
        applies_to,
        params: out_params
            .into_iter()
            .map(|(pn, unit, s)| Param {
                name: leak(pn),
                unit: leak(unit),
                prior_sigma: s,
            })
            .collect(),
        axes,
        file: loc.file.to_path_buf(),
    })
}

/// Parses an effects file's text; `file` names it in messages. Every error names the file, the
/// line and column, and (when it is inside one) the effect.
pub fn parse_effects(file: &Path, src: &str) -> anyhow::Result<Vec<UserEffect>> {
    let loc = Loc { file, src };
    let def: FileDef = toml::from_str(src).map_err(|e| {
        let span = e.span().unwrap_or(0..0);
        let within = enclosing_effect(src, span.start)
            .map(|(line, name)| match name {
                Some(n) => format!("effect `{n}`: "),
                None => format!("effect starting on line {line}: "),
            })
            .unwrap_or_default();
        anyhow::anyhow!("{}: {within}{}", loc.at(span), e.message().trim_end())
    })?;
    if def.effect.is_empty() {
        anyhow::bail!(
            "{}: no effects: the file must have at least one [[effect]] table",
            file.display()
        );
    }
    let mut out: Vec<UserEffect> = Vec::new();
    for (i, e) in def.effect.iter().enumerate() {
        let u = build_effect(&loc, e.span(), e.get_ref(), i)?;
        if out.iter().any(|o| o.name == u.name) {
            let s = e.get_ref().name.as_ref().map_or(e.span(), |n| n.span());
            return Err(loc.err(s, u.name, "defined twice in this file"));
        }
        out.push(u);
    }
    Ok(out)
}

/// Reads and parses an effects file.
pub fn load_file(path: &Path) -> anyhow::Result<Vec<UserEffect>> {
    let src = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the effects file: {e}", path.display()))?;
    parse_effects(path, &src)
}

/// Loads the given effects files and adds their effects to the catalog for this run
/// ([`crate::catalog::register`]): they are then candidates of the diagnosis, usable with
/// `--with`, and reported like built-in effects. The effects are leaked (`&'static`, one per
/// file and run).
pub fn load_and_register(paths: &[PathBuf]) -> anyhow::Result<Vec<&'static dyn Effect>> {
    let mut all: Vec<&'static dyn Effect> = Vec::new();
    for p in paths {
        for e in load_file(p)? {
            let file = e.file.clone();
            let e: &'static UserEffect = Box::leak(Box::new(e));
            if all.iter().any(|o| o.name() == e.name()) {
                anyhow::bail!(
                    "{}: effect `{}` is already defined in another --effects file",
                    file.display(),
                    e.name()
                );
            }
            all.push(e);
        }
    }
    crate::catalog::register(all.clone())?;
    Ok(all)
}

/// What `identify`, `diagnose` and `report` call first: loads and registers `--effects` files.
pub fn load_effects_args(args: &ModelArgs) -> anyhow::Result<()> {
    if !args.effects.is_empty() {
        load_and_register(&args.effects)?;
    }
    Ok(())
}
