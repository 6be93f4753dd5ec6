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
//! - `up_x`, `up_y`, `up_z`: the local vertical as a unit vector in platform axes, `A/|A|`
//!   (replaced by that formula before parsing, so its derivative reaches the attitude chain);
//! - `north_x`, `north_y`, `north_z`: local north as a unit vector in platform axes
//!   (`Context::north`, differentiated like A: ∂/∂north reaches the attitude chain), and
//!   `east_x`, `east_y`, `east_z` = north × up (replaced by that formula). Up, north and east are
//!   the columns of the attitude C_0^p (frame 0 is ENU);
//! - `t_h`: hours since the start of the run (θ = 0), `Context::t_s / 3600`;
//! - `temp_c`: the platform temperature's *deviation from its value at the first measurement*,
//!   °C (`Context::temp_dev_c`; 0 when the recording has no `temp_c` column). A constant
//!   temperature offset is indistinguishable from the constant drift, so only the deviation is
//!   offered, as for the built-in `temp-drift`;
//! - the effect's own parameters, by name.
//!
//! `abs(u)` is rewritten as `u·s`, `s` the sign of `u` evaluated first (exmex has no derivative
//! of `abs`). A variable not listed here, not a parameter and not a declared recording column is
//! an error at load time.
//!
//! A file is code handed to the tool: it is read and compiled within checked limits
//! ([`MAX_FILE_BYTES`], [`MAX_EFFECTS`], [`MAX_PARAMS`], [`MAX_EXPR_CHARS`], [`MAX_EXPR_DEPTH`],
//! [`MAX_DERIVATIVE_WORK`], [`PRIOR_SIGMA_RANGE`]), and a value that is not finite or beyond [`MAX_REACH`] while the
//! filter runs is recorded for the CLI to report ([`numeric_failure`]).
//!
//! An accelerometer effect adds its value (m/s²) to that axis' accelerometer output; a drift
//! effect adds its value (deg/h) to that gyro's drift rate. Parameters are constants (no
//! Gauss–Markov dynamics).

mod expr;

use std::fmt::Write as _;
use std::io::Read as _;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use estimator_core::effects::{Context, Effect, Param, Partials};
use estimator_core::model::MAX_STATES;
use estimator_core::units::S_PER_H;
use estimator_core::PAPER_STATES;
use exmex::Express as _;
use nalgebra::Matrix3;
use serde::Deserialize;
use toml::Spanned;

use crate::recording::{read_columns, REQUIRED_COLUMNS, TEMP_COLUMN};
use expr::{eval, excerpt, parse_expr, AxisExpr, HIDDEN_PREFIX};
pub(crate) use expr::{MAX_DERIVATIVE_WORK, VARIABLES};
pub use expr::{MAX_EXPR_CHARS, MAX_EXPR_DEPTH};

const AXES: [&str; 3] = ["x", "y", "z"];

/// Largest effects file read, bytes: a file of effects is a few kilobytes; `/dev/zero` or a
/// recording given by mistake must not be read forever or into memory whole.
pub(crate) const MAX_FILE_BYTES: u64 = 1 << 20;
/// Most effects in one file (each is a candidate the diagnosis refits).
pub(crate) const MAX_EFFECTS: usize = 32;
/// Most parameters of one effect: the filter holds [`MAX_STATES`] states, the paper's model takes
/// [`PAPER_STATES`] of them (1 000 parameters grew to 24 GB, 3 000 overflowed the stack).
pub(crate) const MAX_PARAMS: usize = MAX_STATES - PAPER_STATES;
/// Range of a parameter's `prior_sigma` (in its unit): the filter squares it and multiplies
/// squares (1e300 overflowed to infinity, 1e-300 underflows to zero). What the prior lets the
/// effect reach is checked too ([`MAX_REACH`]).
pub(crate) const PRIOR_SIGMA_RANGE: (f64, f64) = (1e-30, 1e30);
/// Largest size an effect may reach, in its unit (m/s² or deg/h): its value, or a derivative
/// times the parameter's prior 1σ. The recording reader refuses |a| > 1000 m/s²; a paper run
/// identified with an effect of reach 1e6 m/s², failed at 1e7 (not positive definite).
pub(crate) const MAX_REACH: f64 = 1e3;
/// Most recording columns one effect may use.
pub(crate) const MAX_COLUMNS: usize = 8;

/// Where an effect adds its value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum AppliesTo {
    /// Accelerometer output, m/s².
    Accelerometer,
    /// Gyro drift rate, deg/h.
    Drift,
}

/// An effect read from a TOML file, owned by the run's [`crate::catalog::Catalog`] with its name
/// and about; its parameters' names and units are leaked once per run (see `leak`).
#[derive(Debug)]
pub struct UserEffect {
    name: String,
    about: String,
    applies_to: AppliesTo,
    params: Vec<Param>,
    axes: [AxisExpr; 3],
    /// `file:line:column` of the name, of each parameter's name and of each axis expression.
    name_at: String,
    params_at: Vec<String>,
    axes_at: [String; 3],
    /// The recording columns the expressions use (`columns = [...]`), the place of that key,
    /// and their values over the run they are bound to ([`bind_columns`]).
    columns: Vec<String>,
    columns_at: String,
    table: std::sync::RwLock<Option<std::sync::Arc<ColumnTable>>>,
    /// The first value or derivative that was not a finite number, described (see
    /// [`UserEffect::numeric_failure`]).
    failure: OnceLock<String>,
}

impl UserEffect {
    /// The first evaluation that gave a value or derivative that is not a finite number (the
    /// square root or logarithm of a negative number, ln(0), an overflowing exp, …), as a
    /// message naming the file, line, effect, expression and the values of its variables. The
    /// filter cannot be told by the effect (the [`Effect`] trait returns no error); the host
    /// asks after a run ([`numeric_failure`]).
    pub fn numeric_failure(&self) -> Option<&str> {
        self.failure.get().map(String::as_str)
    }

    /// Records the first numeric failure: `problem` says what was wrong at parameters `p`.
    fn record_failure(&self, axis: usize, problem: &str, p: &[f64], ctx: &Context) {
        if self.failure.get().is_some() {
            return;
        }
        let a = ctx.specific_force;
        let mut vals = format!(
            "t = {:.4} h (A = [{:.6}, {:.6}, {:.6}] m/s^2, temp_c = {:.3}",
            ctx.t_s / S_PER_H,
            a[0],
            a[1],
            a[2],
            ctx.temp_dev_c
        );
        for (q, x) in self.params.iter().zip(p) {
            let _ = write!(vals, ", {} = {x:.3e}", q.name);
        }
        vals.push(')');
        let _ = self.failure.set(format!(
            "{}: effect `{}`: {} = \"{}\": at {vals} {problem}",
            self.axes_at[axis],
            self.name,
            AXES[axis],
            excerpt(&self.axes[axis].source)
        ));
    }

    /// Checks one value (`what`: "value" or "derivative by K", `sigma`: the prior 1σ it is
    /// multiplied by, 1 for the value): not finite, or reaching beyond [`MAX_REACH`].
    fn check_value(&self, axis: usize, what: &str, v: f64, sigma: f64, p: &[f64], ctx: &Context) {
        let unit = match self.applies_to {
            AppliesTo::Accelerometer => "m/s^2",
            AppliesTo::Drift => "deg/h",
        };
        if !v.is_finite() {
            let problem = format!(
                "its {what} is {v}, not a finite number: a square root or logarithm of a \
                 negative number or of zero, a division by zero or an overflow; write the \
                 expression so that it is defined for every value its variables take"
            );
            self.record_failure(axis, &problem, p, ctx);
        } else if (v * sigma).abs() > MAX_REACH {
            let times = if sigma == 1.0 {
                String::new()
            } else {
                format!(" times its prior_sigma {sigma:e}")
            };
            let problem = format!(
                "its {what}{times} is {:.3e} {unit}, beyond the {MAX_REACH:e} {unit} an effect may \
                 reach (the filter loses every significant digit there); check the expression \
                 (an overflowing exp?) and the parameter's unit and prior_sigma",
                v * sigma
            );
            self.record_failure(axis, &problem, p, ctx);
        }
    }

    /// The values of the effect's recording columns at the context's time (NaN, recorded as a
    /// failure, when no recording is bound).
    fn column_values(&self, p: &[f64], ctx: &Context) -> smallvec::SmallVec<[f64; 4]> {
        if self.columns.is_empty() {
            return smallvec::SmallVec::new();
        }
        let table = self.table.read().unwrap_or_else(|e| e.into_inner());
        match table.as_ref() {
            Some(t) => (0..self.columns.len()).map(|k| t.at(k, ctx.t_s)).collect(),
            None => {
                drop(table);
                let problem = format!(
                    "the recording columns {} have no values: no recording was bound to the effect",
                    self.columns.join(", ")
                );
                self.record_failure(0, &problem, p, ctx);
                smallvec::smallvec![f64::NAN; self.columns.len()]
            }
        }
    }

    fn contribute(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        for d in out.d_params.iter_mut() {
            *d = nalgebra::Vector3::zeros();
        }
        let cols = self.column_values(p, ctx);
        for (i, ax) in self.axes.iter().enumerate() {
            let vars = ax.bind(p, ctx, &cols);
            let v = ax.value(&vars);
            if !v.abs().le(&MAX_REACH) {
                self.check_value(i, "value", v, 1.0, p, ctx);
            }
            out.value[i] += v;
            for (k, d) in &ax.d_params {
                let v = eval(d, &vars);
                let q = &self.params[*k];
                if !(v * q.prior_sigma).abs().le(&MAX_REACH) {
                    self.check_value(
                        i,
                        &format!("derivative by {}", q.name),
                        v,
                        q.prior_sigma,
                        p,
                        ctx,
                    );
                }
                out.d_params[*k][i] = v;
            }
            for (j, d) in &ax.d_force {
                let v = eval(d, &vars);
                if !v.is_finite() {
                    self.check_value(i, &format!("derivative by A_{}", AXES[*j]), v, 1.0, p, ctx);
                }
                out.d_force[(i, *j)] += v;
            }
        }
    }
}

impl UserEffect {
    /// Adds ∂value/∂north of each axis (rows) to `d_north` (the model asks for it apart from
    /// the value: [`Effect::d_north`]).
    fn add_d_north(&self, p: &[f64], ctx: &Context, d_north: &mut Matrix3<f64>) {
        let cols = self.column_values(p, ctx);
        for (i, ax) in self.axes.iter().enumerate() {
            if ax.d_north.is_empty() {
                continue;
            }
            let vars = ax.bind(p, ctx, &cols);
            for (j, d) in &ax.d_north {
                let v = eval(d, &vars);
                if !v.is_finite() {
                    let what = format!("derivative by north_{}", AXES[*j]);
                    self.check_value(i, &what, v, 1.0, p, ctx);
                }
                d_north[(i, *j)] += v;
            }
        }
    }
}

impl Effect for UserEffect {
    fn name(&self) -> &str {
        &self.name
    }
    fn about(&self) -> &str {
        &self.about
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
    fn uses_north(&self) -> bool {
        self.axes.iter().any(AxisExpr::uses_north)
    }
    fn d_north(&self, p: &[f64], ctx: &Context, drift: bool, d_north: &mut Matrix3<f64>) {
        if drift == (self.applies_to == AppliesTo::Drift) {
            self.add_d_north(p, ctx, d_north);
        }
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
    columns: Option<Spanned<Vec<Spanned<String>>>>,
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

/// Leaks a string for the `&'static str` of a [`Param`] (a parameter's name and unit): the
/// identification's results carry parameter names as `&'static str` (`Identification::params`,
/// the coefficient rows, a refit's drift), so a file effect's cannot borrow from the catalog yet.
/// Bounded: a run loads each user file once, a few short strings per parameter.
fn leak(s: &str) -> &'static str {
    Box::leak(s.to_owned().into_boxed_str())
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
        .map(|(n, f)| {
            let a = nalgebra::Vector3::from(*f);
            Context {
                t_s: 3600.0 * (1.7 + 13.0 * n as f64),
                specific_force: a,
                temp_dev_c: -2.3 + 1.9 * n as f64,
                // A unit vector orthogonal to A, as north is to up.
                north: a
                    .cross(&nalgebra::Vector3::new(0.36, -0.48, 0.8))
                    .normalize(),
            }
        })
        .collect()
}

/// Checks the effect's name and kind; `span` locates its table.
fn name_and_kind<'d>(
    loc: &Loc<'_>,
    span: &Range<usize>,
    def: &'d EffectDef,
    index: usize,
) -> anyhow::Result<(&'d Spanned<String>, AppliesTo)> {
    let Some(name) = &def.name else {
        return Err(anyhow::anyhow!(
            "{}: effect #{} has no `name`",
            loc.at(span.clone()),
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
            &excerpt(n),
            "the name must be non-empty and use only letters, digits, `-` and `_` (it is typed after --with)",
        ));
    }
    let kind = match def.applies_to.as_ref() {
        None => {
            return Err(loc.err(
                span.clone(),
                n,
                "no `applies_to` (\"accelerometer\" or \"drift\")",
            ))
        }
        Some(a) => match a.get_ref().as_str() {
            "accelerometer" => AppliesTo::Accelerometer,
            "drift" => AppliesTo::Drift,
            other => {
                return Err(loc.err(
                    a.span(),
                    n,
                    format!(
                        "applies_to = \"{}\": must be \"accelerometer\" or \"drift\"",
                        excerpt(other)
                    ),
                ))
            }
        },
    };
    Ok((name, kind))
}

/// Checks one parameter against the names taken so far (`names`).
fn check_param(loc: &Loc<'_>, n: &str, pd: &ParamDef, names: &[&str]) -> anyhow::Result<()> {
    let pn = pd.name.get_ref().as_str();
    let refuse = |msg: String| Err(loc.err(pd.name.span(), n, msg));
    if let Some(p) = variable_name_problem(pn) {
        return refuse(format!("parameter name {p}"));
    }
    if names.contains(&pn) {
        return refuse(format!("parameter `{pn}` given twice"));
    }
    let s = *pd.prior_sigma.get_ref();
    let (lo, hi) = PRIOR_SIGMA_RANGE;
    if !(s.is_finite() && s > 0.0) {
        return Err(loc.err(
            pd.prior_sigma.span(),
            n,
            format!("parameter `{pn}`: prior_sigma = {s} must be a finite positive number"),
        ));
    }
    if !(lo..=hi).contains(&s) {
        return Err(loc.err(
            pd.prior_sigma.span(),
            n,
            format!(
                "parameter `{pn}`: prior_sigma = {s:e} must be a number from {lo:e} to {hi:e} \
                 (in the parameter's unit; choose the unit so the prior is in this range)"
            ),
        ));
    }
    Ok(())
}

/// The effect's parameters, checked; `span` locates its table.
fn build_params<'d>(
    loc: &Loc<'_>,
    span: &Range<usize>,
    n: &str,
    def: &'d EffectDef,
) -> anyhow::Result<(Vec<&'d ParamDef>, Vec<String>)> {
    let Some(params) = def.params.as_ref().filter(|p| !p.get_ref().is_empty()) else {
        let at = def.params.as_ref().map_or(span.clone(), |p| p.span());
        return Err(loc.err(
            at,
            n,
            "no parameters: give `params = [ { name = …, unit = …, prior_sigma = … }, … ]`",
        ));
    };
    if params.get_ref().len() > MAX_PARAMS {
        return Err(loc.err(
            params.span(),
            n,
            format!(
                "{} parameters; an effect may have at most {MAX_PARAMS} (the filter holds \
                 {MAX_STATES} states, {PAPER_STATES} of them the paper's model's)",
                params.get_ref().len()
            ),
        ));
    }
    let mut names: Vec<&str> = Vec::new();
    let mut out = Vec::new();
    let mut at = Vec::new();
    for p in params.get_ref() {
        let pd = p.get_ref();
        check_param(loc, n, pd, &names)?;
        names.push(pd.name.get_ref());
        at.push(loc.at(pd.name.span()));
        out.push(pd);
    }
    Ok((out, at))
}

/// Checks a name the expressions will use as a variable (a parameter's or a column's): an
/// identifier that is not a reserved variable nor a function or constant of the language.
fn variable_name_problem(v: &str) -> Option<String> {
    if !is_identifier(v) {
        return Some(format!(
            "`{}`: must be a letter or `_` followed by letters, digits or `_`",
            excerpt(v)
        ));
    }
    if VARIABLES.iter().any(|(r, _)| *r == v) || v.starts_with(HIDDEN_PREFIX) {
        return Some(format!("`{v}` is a reserved variable"));
    }
    // exmex reads some names as operators or constants (`sin`, `E`, `PI`, …).
    let as_var = parse_expr(v)
        .map(|e| e.var_names() == [v.to_string()])
        .unwrap_or(false);
    (!as_var).then(|| format!("`{v}` is a function or constant of the expression language"))
}

/// The recording columns the effect declares (`columns = ["I_spin"]`), checked, and the place
/// of the key; `span` locates the effect's table.
fn build_columns<'d>(
    loc: &Loc<'_>,
    span: &Range<usize>,
    n: &str,
    def: &'d EffectDef,
    params: &[&str],
) -> anyhow::Result<(Vec<&'d str>, String)> {
    let Some(cols) = &def.columns else {
        return Ok((Vec::new(), loc.at(span.clone())));
    };
    if cols.get_ref().len() > MAX_COLUMNS {
        return Err(loc.err(
            cols.span(),
            n,
            format!(
                "{} columns; an effect may use at most {MAX_COLUMNS}",
                cols.get_ref().len()
            ),
        ));
    }
    let mut out: Vec<&str> = Vec::new();
    for c in cols.get_ref() {
        let name = c.get_ref().as_str();
        let problem = variable_name_problem(name)
            .map(|p| format!("column {p}"))
            .or_else(|| {
                (REQUIRED_COLUMNS.contains(&name) || name == TEMP_COLUMN).then(|| {
                    format!("column `{name}` is the recording's own, not an extra column (use A_x…, temp_c)")
                })
            })
            .or_else(|| params.contains(&name).then(|| format!("column `{name}` is also a parameter")))
            .or_else(|| out.contains(&name).then(|| format!("column `{name}` given twice")));
        if let Some(p) = problem {
            return Err(loc.err(c.span(), n, p));
        }
        out.push(name);
    }
    Ok((out, loc.at(cols.span())))
}

/// Compiles the three axis expressions; `span` locates the effect's table.
fn build_axes(
    loc: &Loc<'_>,
    span: &Range<usize>,
    n: &str,
    def: &EffectDef,
    names: &[&str],
    columns: &[&str],
) -> anyhow::Result<([AxisExpr; 3], [String; 3])> {
    let mut axes = Vec::with_capacity(3);
    let mut at = Vec::with_capacity(3);
    let mut budget = MAX_DERIVATIVE_WORK;
    for (i, e) in [&def.x, &def.y, &def.z].into_iter().enumerate() {
        let Some(e) = e else {
            return Err(loc.err(
                span.clone(),
                n,
                format!(
                    "no `{}` expression (all of x, y and z are required; write \"0\" for an axis the effect does not touch)",
                    AXES[i]
                ),
            ));
        };
        let (ax, work) = expr::compile(e.get_ref(), names, columns, budget).map_err(|why| {
            let what = format!("{} = \"{}\"", AXES[i], excerpt(e.get_ref()));
            loc.err(e.span(), n, format!("{what}: {why}"))
        })?;
        budget -= work;
        axes.push(ax);
        at.push(loc.at(e.span()));
    }
    let three = "three axes";
    Ok((axes.try_into().expect(three), at.try_into().expect(three)))
}

/// Refuses a parameter that no expression moves: it could not be identified.
fn check_identifiable(
    loc: &Loc<'_>,
    n: &str,
    axes: &[AxisExpr; 3],
    params: &[&ParamDef],
) -> anyhow::Result<()> {
    let probes = probe_contexts();
    let p_probe: Vec<f64> = (0..params.len()).map(|m| 0.37 + 0.11 * m as f64).collect();
    for (k, pd) in params.iter().enumerate() {
        let uses = |ax: &&AxisExpr| ax.d_params.iter().any(|(kk, _)| *kk == k);
        let moves = axes.iter().filter(uses).any(|ax| {
            ax.d_params.iter().any(|(kk, d)| {
                *kk == k
                    && probes.iter().any(|ctx| {
                        // Column values vary between the probes as the others do.
                        let cols: Vec<f64> = (0..MAX_COLUMNS)
                            .map(|m| 1.3 + 0.7 * m as f64 + 0.5 * ctx.temp_dev_c)
                            .collect();
                        let v = eval(d, &ax.bind(&p_probe, ctx, &cols));
                        v != 0.0 && !v.is_nan()
                    })
            })
        });
        if !moves {
            let why = if axes.iter().any(|ax| uses(&ax)) {
                "has a zero partial derivative everywhere we probed it"
            } else {
                "appears in none of x, y, z"
            };
            let msg = format!(
                "parameter `{}` {why}: it does not change the effect's value, so it cannot be identified",
                pd.name.get_ref()
            );
            return Err(loc.err(pd.name.span(), n, msg));
        }
    }
    Ok(())
}

/// Builds one effect from its table; `span` locates the table.
fn build_effect(
    loc: &Loc<'_>,
    span: Range<usize>,
    def: &EffectDef,
    index: usize,
) -> anyhow::Result<UserEffect> {
    let (name, applies_to) = name_and_kind(loc, &span, def, index)?;
    let n = name.get_ref().as_str();
    let (params, params_at) = build_params(loc, &span, n, def)?;
    let names: Vec<&str> = params.iter().map(|p| p.name.get_ref().as_str()).collect();
    let (columns, columns_at) = build_columns(loc, &span, n, def, &names)?;
    let (axes, axes_at) = build_axes(loc, &span, n, def, &names, &columns)?;
    check_identifiable(loc, n, &axes, &params)?;
    let about = def
        .about
        .clone()
        .unwrap_or_else(|| format!("User-defined effect from {}.", loc.file.display()));
    Ok(UserEffect {
        name: n.to_string(),
        about,
        applies_to,
        params: params
            .iter()
            .map(|pd| Param {
                name: leak(pd.name.get_ref()),
                unit: leak(&pd.unit),
                prior_sigma: *pd.prior_sigma.get_ref(),
            })
            .collect(),
        axes,
        name_at: loc.at(name.span()),
        params_at,
        axes_at,
        columns: columns.iter().map(|c| c.to_string()).collect(),
        columns_at,
        table: std::sync::RwLock::new(None),
        failure: OnceLock::new(),
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
                Some(n) => format!("effect `{}`: ", excerpt(&n)),
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
    if let Some(e) = def.effect.get(MAX_EFFECTS) {
        anyhow::bail!(
            "{}: {} effects in the file; at most {MAX_EFFECTS} are accepted (each is a candidate the diagnosis refits)",
            loc.at(e.span()),
            def.effect.len()
        );
    }
    let mut out: Vec<UserEffect> = Vec::new();
    for (i, e) in def.effect.iter().enumerate() {
        let u = build_effect(&loc, e.span(), e.get_ref(), i)?;
        if let Some(o) = out.iter().find(|o| o.name == u.name) {
            return Err(anyhow::anyhow!(
                "{}: effect `{}`: defined twice in this file (first at {})",
                u.name_at,
                u.name,
                o.name_at
            ));
        }
        out.push(u);
    }
    Ok(out)
}

/// Reads at most [`MAX_FILE_BYTES`] of an effects file (a larger file, `/dev/zero` or a FIFO
/// that never ends is refused after that many bytes) and parses it.
pub fn load_file(path: &Path) -> anyhow::Result<Vec<UserEffect>> {
    let name = path.display();
    let f = std::fs::File::open(path)
        .map_err(|e| anyhow::anyhow!("{name}: cannot read the effects file: {e}"))?;
    let mut bytes = Vec::new();
    f.take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| anyhow::anyhow!("{name}: cannot read the effects file: {e}"))?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        anyhow::bail!(
            "{name}: more than {MAX_FILE_BYTES} bytes: not an effects file (an effects file is a few kilobytes of TOML; the limit is {} MiB)",
            MAX_FILE_BYTES >> 20
        );
    }
    let src = String::from_utf8(bytes).map_err(|e| {
        let ok = e.utf8_error().valid_up_to();
        let text = String::from_utf8_lossy(&e.as_bytes()[..ok]).into_owned();
        let (line, col) = line_col(&text, ok);
        anyhow::anyhow!(
            "{name}:{line}:{col}: not valid UTF-8 (byte 0x{:02x}); an effects file is UTF-8 text",
            e.as_bytes()[ok]
        )
    })?;
    parse_effects(path, &src)
}

/// Refuses an effect whose name or a parameter's name is taken by a `builtin` effect or by an
/// effect loaded before it (`loaded`), naming the file and line of both.
fn check_clash(
    e: &UserEffect,
    loaded: &[UserEffect],
    builtin: &[&dyn Effect],
) -> anyhow::Result<()> {
    if let Some(o) = loaded.iter().find(|o| o.name == e.name) {
        let same = if o.name_at == e.name_at {
            " (the same file given twice)"
        } else {
            ""
        };
        anyhow::bail!(
            "{}: effect `{}`: already defined at {}{same}",
            e.name_at,
            e.name,
            o.name_at
        );
    }
    if builtin.iter().any(|c| c.name() == e.name) {
        anyhow::bail!(
            "{}: effect `{}`: the name is taken by a built-in effect of the catalog; rename it",
            e.name_at,
            e.name
        );
    }
    for (p, at) in e.params.iter().zip(&e.params_at) {
        if let Some(c) = builtin
            .iter()
            .find(|c| c.params().iter().any(|q| q.name == p.name))
        {
            anyhow::bail!(
                "{at}: effect `{}`: parameter name `{}` is already used by the catalog's effect `{}`; rename it",
                e.name,
                p.name,
                c.name()
            );
        }
        let other = loaded.iter().find_map(|o| {
            o.params
                .iter()
                .zip(&o.params_at)
                .find(|(q, _)| q.name == p.name)
        });
        if let Some((_, o_at)) = other {
            anyhow::bail!(
                "{at}: effect `{}`: parameter name `{}` is already used at {o_at}; rename it",
                e.name,
                p.name
            );
        }
    }
    Ok(())
}

/// Loads the given effects files, in order, for [`crate::catalog::Catalog::load`]: an effect
/// whose name or a parameter's name is taken by one of the `builtin` effects or by an effect
/// loaded before it is refused, naming the file and line of both.
pub(crate) fn load_files(
    paths: &[PathBuf],
    builtin: &[&dyn Effect],
) -> anyhow::Result<Vec<UserEffect>> {
    let mut loaded: Vec<UserEffect> = Vec::new();
    for p in paths {
        for e in load_file(p)? {
            check_clash(&e, &loaded, builtin)?;
            loaded.push(e);
        }
    }
    Ok(loaded)
}

/// The values of an effect's recording columns over one run, interpolated linearly in time.
#[derive(Debug)]
struct ColumnTable {
    /// The recording they were read from.
    path: PathBuf,
    /// Sample times, s (as the filter sees them: relative to the first sample).
    t_s: Vec<f64>,
    /// One vector per declared column, one value per sample.
    values: Vec<Vec<f64>>,
}

impl ColumnTable {
    /// Column `k` at time `t_s`: linear between the samples around it, the end values outside.
    fn at(&self, k: usize, t_s: f64) -> f64 {
        let (t, v) = (&self.t_s, &self.values[k]);
        let i = t.partition_point(|&x| x <= t_s);
        if i == 0 {
            return v[0];
        }
        if i == t.len() {
            return v[i - 1];
        }
        let w = (t_s - t[i - 1]) / (t[i] - t[i - 1]);
        v[i - 1] + w * (v[i] - v[i - 1])
    }
}

/// Binds the recording columns of the loaded file effects that use some to the recording at
/// `path` (its samples, times relative as the filter sees them, and their file `lines`): reads
/// the columns by header name. Nothing to do without such effects. A missing column or a bad
/// value is an error naming the effect and the recording's line; a second recording is refused
/// (the effect holds one run's columns: joint fits with extra columns are not supported yet).
pub(crate) fn bind_columns(
    loaded: &[UserEffect],
    path: &Path,
    samples: &[crate::recording::RawSample],
    lines: &[u32],
) -> anyhow::Result<()> {
    for e in loaded.iter().filter(|e| !e.columns.is_empty()) {
        let mut table = e.table.write().unwrap_or_else(|e| e.into_inner());
        if let Some(t) = table.as_ref() {
            if t.path == path {
                continue;
            }
            anyhow::bail!(
                "{}: effect `{}` uses the recording columns {} of {}; it cannot also be fitted to {} (joint fits with extra columns are not supported yet)",
                e.columns_at,
                e.name,
                e.columns.join(", "),
                t.path.display(),
                path.display()
            );
        }
        let values = read_columns(path, &e.columns, lines)
            .map_err(|err| anyhow::anyhow!("{}: effect `{}`: {err:#}", e.columns_at, e.name))?;
        *table = Some(std::sync::Arc::new(ColumnTable {
            path: path.to_path_buf(),
            t_s: samples.iter().map(|s| s.t_s).collect(),
            values,
        }));
    }
    Ok(())
}

/// The first numeric failure of the `loaded` file effects (see
/// [`UserEffect::numeric_failure`]); the CLI ends with it (exit 2).
pub(crate) fn numeric_failure(loaded: &[UserEffect]) -> Option<String> {
    loaded
        .iter()
        .find_map(|e| e.numeric_failure().map(str::to_string))
}
