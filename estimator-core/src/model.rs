//! The platform model: state layout, the angle rate f(x) with its analytic Jacobian F, and the
//! accelerometer measurement h(x) with its analytic Jacobian H (paper eqs. 5, 7–10).
//!
//! State: `[tx, ty, tz]` (rad) followed by the parameter blocks of the model's effects, in order.
//! The first effect is normally [`crate::effects::PaperDrift`] (the 12 drift coefficients).

use nalgebra::{Matrix3, Vector3};

use crate::effects::{Context, Effect, Markov, Param, Partials};
use crate::frames::{Attitude, Site};
use crate::kinematics::{d_rate_to_euler, rate_to_euler};
use crate::units::RADPS_PER_DEGPH;

/// Number of platform-angle states at the head of the state vector.
pub const ANGLES: usize = 3;
/// Largest state the model accepts (the host's capacity; the firmware uses less).
pub const MAX_STATES: usize = 64;
/// Largest number of effects in one model.
pub const MAX_EFFECTS: usize = 12;
/// Largest number of states with dynamics (3 angles + Gauss–Markov states).
pub const MAX_DYNAMIC: usize = 6;

/// How the state and its transition matrix are carried over one filter period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Propagation {
    /// Classic 4th-order Runge–Kutta on the state, in sub-steps of at most `max_step_s`
    /// (default 60 s: one step of 60 s is exact to ~2.5e-10 m/s²); Φ of each sub-step is the
    /// exponential of F at its midpoint ([`crate::propagate::propagate`]).
    Rk4 {
        /// Largest integration sub-step, s.
        max_step_s: f64,
    },
    /// The paper's `X + f(X)·dt`, `Φ = I + F·dt` (kept to reproduce its figures; not accurate).
    Euler,
}

impl Default for Propagation {
    fn default() -> Self {
        Propagation::Rk4 { max_step_s: 60.0 }
    }
}

/// Why a model cannot be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(missing_docs)] // fields: state counts
pub enum ModelError {
    /// More than [`MAX_EFFECTS`] effects.
    TooManyEffects,
    /// More than the state capacity (`needed`, `capacity`).
    TooManyStates { needed: usize, capacity: usize },
    /// More than [`MAX_DYNAMIC`] states with dynamics.
    TooManyDynamicStates,
}

impl core::fmt::Display for ModelError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ModelError::TooManyEffects => write!(f, "more than {MAX_EFFECTS} effects in one model"),
            ModelError::TooManyStates { needed, capacity } => {
                write!(
                    f,
                    "the model needs {needed} states but the filter holds {capacity}"
                )
            }
            ModelError::TooManyDynamicStates => {
                write!(f, "more than {} Gauss-Markov states", MAX_DYNAMIC - ANGLES)
            }
        }
    }
}

/// The process and measurement model: site, effects (state layout) and noise.
#[derive(Clone, Copy)]
pub struct Model<'m> {
    site: Site,
    /// Gravity and Earth rate in the site's chart frame (computed once: every f and h uses them).
    gravity_r: Vector3<f64>,
    earth_rate_r: Vector3<f64>,
    /// Local north in the chart frame (unit), for [`Context::north`]; NaN when no effect
    /// [`Effect::uses_north`] (then neither north nor its chain is computed).
    north_r: Vector3<f64>,
    effects: &'m [&'m dyn Effect],
    offsets: [usize; MAX_EFFECTS + 1],
    /// Indices of states with dynamics (angles first, then Gauss–Markov states).
    dynamic: [usize; MAX_DYNAMIC],
    n_dynamic: usize,
    /// Gauss–Markov parameters of each dynamic state (unused for the angles).
    markov: [Markov; MAX_DYNAMIC],
    /// States that enter the measurement (angles + accelerometer-effect parameters), as a bit set.
    measured: u64,
    arw_rad2ps: f64,
    propagation: Propagation,
}

impl<'m> Model<'m> {
    /// A model of the platform at `site` with the given effects (the paper's drift first, as a
    /// rule), gyro rate-noise density `arw_rad2ps` (rad²/s per axis; see
    /// [`crate::units::arw_deg2ph_to_rad2ps`]) and propagation method.
    #[inline] // cold set-up: compiled in its (opt-level "z") caller in the firmware, issue 10
    pub fn new(
        site: Site,
        effects: &'m [&'m dyn Effect],
        arw_rad2ps: f64,
        propagation: Propagation,
    ) -> Result<Self, ModelError> {
        if effects.len() > MAX_EFFECTS {
            return Err(ModelError::TooManyEffects);
        }
        let mut offsets = [0; MAX_EFFECTS + 1];
        let mut dynamic = [0; MAX_DYNAMIC];
        let mut markov = [Markov {
            tau_s: f64::INFINITY,
            q: 0.0,
        }; MAX_DYNAMIC];
        dynamic[..ANGLES].copy_from_slice(&[0, 1, 2]);
        let mut n_dynamic = ANGLES;
        let mut measured: u64 = 0b111;
        let mut n = ANGLES;
        for (e, effect) in effects.iter().enumerate() {
            offsets[e] = n;
            let dim = effect.params().len();
            if n + dim > MAX_STATES {
                return Err(ModelError::TooManyStates {
                    needed: n + dim,
                    capacity: MAX_STATES,
                });
            }
            for k in 0..dim {
                if let Some(m) = effect.markov(k) {
                    if n_dynamic == MAX_DYNAMIC {
                        return Err(ModelError::TooManyDynamicStates);
                    }
                    dynamic[n_dynamic] = n + k;
                    markov[n_dynamic] = m;
                    n_dynamic += 1;
                }
                if effect.touches_accel() {
                    measured |= 1 << (n + k);
                }
            }
            n += dim;
        }
        offsets[effects.len()] = n;
        Ok(Model {
            site,
            gravity_r: site.gravity_r(),
            earth_rate_r: site.earth_rate_r(),
            north_r: if effects.iter().any(|e| e.uses_north()) {
                site.north_r()
            } else {
                Vector3::repeat(f64::NAN)
            },
            effects,
            offsets,
            dynamic,
            n_dynamic,
            markov,
            measured,
            arw_rad2ps,
            propagation,
        })
    }

    /// Number of states.
    pub fn dim(&self) -> usize {
        self.offsets[self.effects.len()]
    }
    /// The site (latitude, gravity).
    pub fn site(&self) -> &Site {
        &self.site
    }
    /// The effects, in state order.
    pub fn effects(&self) -> &'m [&'m dyn Effect] {
        self.effects
    }
    /// First state index of effect `e`.
    pub fn offset(&self, e: usize) -> usize {
        self.offsets[e]
    }
    /// Gyro rate-noise spectral density, rad²/s per axis.
    pub fn arw_rad2ps(&self) -> f64 {
        self.arw_rad2ps
    }
    /// The propagation method.
    pub fn propagation(&self) -> Propagation {
        self.propagation
    }
    /// Indices of the states with dynamics (the angles, then Gauss–Markov states).
    pub fn dynamic_states(&self) -> &[usize] {
        &self.dynamic[..self.n_dynamic]
    }
    /// Gauss–Markov dynamics of the `r`-th dynamic state (`r ≥ 3`).
    pub fn markov(&self, r: usize) -> Markov {
        self.markov[r]
    }
    /// Whether state `i` enters the measurement directly (H column may be non-zero).
    pub fn is_measured(&self, i: usize) -> bool {
        self.measured >> i & 1 == 1
    }
    /// The states that enter the measurement directly as a bit set (bit i: H column i may be
    /// non-zero): the angles and the accelerometer-effect parameters.
    pub fn measured_mask(&self) -> u64 {
        self.measured
    }
    /// The effect owning state `i ≥ 3` and the parameter's index within it.
    #[inline] // cold set-up: compiled in its (opt-level "z") caller in the firmware, issue 10
    pub fn owner(&self, i: usize) -> Option<(usize, usize)> {
        (0..self.effects.len())
            .find(|&e| i >= self.offsets[e] && i < self.offsets[e + 1])
            .map(|e| (e, i - self.offsets[e]))
    }
    /// Name, unit and prior of state `i` (angles are reported as `tx`, `ty`, `tz` in rad).
    #[inline] // cold set-up: compiled in its (opt-level "z") caller in the firmware, issue 10
    pub fn param(&self, i: usize) -> Param {
        const ANG: [&str; 3] = ["tx", "ty", "tz"];
        match self.owner(i) {
            Some((e, k)) => {
                let mut p = self.effects[e].params()[k];
                p.prior_sigma = self.effects[e].prior_sigma(k);
                p
            }
            None => Param {
                name: ANG[i.min(2)],
                unit: "rad",
                prior_sigma: 0.0,
            },
        }
    }
    /// Index of the state named `name`, if any.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        (ANGLES..self.dim()).find(|&i| self.param(i).name == name)
    }

    fn context(&self, att: &Attitude, t_s: f64, temp_dev_c: f64) -> Context {
        Context {
            t_s,
            specific_force: att.specific_force(&self.gravity_r),
            temp_dev_c,
            north: if self.uses_north() {
                att.c * self.north_r
            } else {
                self.north_r
            },
        }
    }

    /// Whether an effect of the model uses north ([`Effect::uses_north`]).
    fn uses_north(&self) -> bool {
        !self.north_r.x.is_nan()
    }

    /// Adds the effects' ∂value/∂θ_j through north to the angle columns `d_dx[0..3]`: drift
    /// terms (`drift`, deg/h) mapped by `map` (K in rad/s per deg/h: F's angle rows), else
    /// accelerometer terms (m/s²: H's angle columns). `Σ ∂value/∂north · ∂north/∂θ_j`, north =
    /// C·north_r. Not inlined and called only when [`Model::uses_north`]: F and H of the
    /// paper's model carry one test for it (the firmware's flash and time).
    #[inline(never)]
    fn add_through_north(
        &self,
        x: &[f64],
        att: &Attitude,
        ctx: &Context,
        map: Option<&Matrix3<f64>>,
        d_dx: &mut [Vector3<f64>],
    ) {
        let drift = map.is_some();
        let mut d_north = Matrix3::zeros();
        for (e, effect) in self.effects.iter().enumerate() {
            let touches = if drift {
                effect.touches_drift()
            } else {
                effect.touches_accel()
            };
            if touches && effect.uses_north() {
                let p = &x[self.offsets[e]..self.offsets[e + 1]];
                effect.d_north(p, ctx, drift, &mut d_north);
            }
        }
        let dn = d_rotated(att, &ctx.north, &self.north_r);
        for j in 0..ANGLES {
            let through = d_north * dn[j];
            d_dx[j] += match map {
                Some(m) => m * through,
                None => through,
            };
        }
    }

    /// Total gyro drift rate at state `x`, deg/h along the platform axes (for reports).
    pub fn drift_rate(
        &self,
        x: &[f64],
        t_s: f64,
        temp_dev_c: f64,
        scratch: &mut [Vector3<f64>],
    ) -> Vector3<f64> {
        let att = Attitude::new(&Vector3::new(x[0], x[1], x[2]));
        let ctx = self.context(&att, t_s, temp_dev_c);
        let (drift, _) = self.effect_terms(x, &ctx, scratch, true);
        drift
    }

    /// Sum of drift (`drift = true`, deg/h) or accelerometer (m/s²) terms of all effects, their
    /// ∂/∂A, and their ∂/∂parameters written into `d_dx[3..dim()]` (zero for the effects that do
    /// not contribute; the angle columns 0..3 are left to the caller).
    fn effect_terms(
        &self,
        x: &[f64],
        ctx: &Context,
        d_dx: &mut [Vector3<f64>],
        drift: bool,
    ) -> (Vector3<f64>, Matrix3<f64>) {
        let mut value = Vector3::zeros();
        let mut d_force = Matrix3::zeros();
        for (e, effect) in self.effects.iter().enumerate() {
            let (a, b) = (self.offsets[e], self.offsets[e + 1]);
            let out = Partials {
                value: &mut value,
                d_params: &mut d_dx[a..b],
                d_force: &mut d_force,
            };
            // An effect sets all its columns (the `Partials` contract, tested for the catalog);
            // only the blocks of effects not called here are cleared.
            if drift && effect.touches_drift() {
                effect.drift(&x[a..b], ctx, out);
            } else if !drift && effect.touches_accel() {
                effect.accel_error(&x[a..b], ctx, out);
            } else {
                out.d_params.iter_mut().for_each(|c| *c = Vector3::zeros());
            }
        }
        (value, d_force)
    }

    /// Platform angle rate θ̇ (rad/s) at state `x`, and its Jacobian: `d_dx[j] = ∂θ̇/∂x_j`
    /// (`d_dx.len() ≥ dim()`). This is rows 0..3 of f and F.
    pub fn angle_rate(
        &self,
        x: &[f64],
        t_s: f64,
        temp_dev_c: f64,
        d_dx: &mut [Vector3<f64>],
    ) -> Vector3<f64> {
        self.rate(x, t_s, temp_dev_c, d_dx, true)
    }

    /// Platform angle rate θ̇ (rad/s) at state `x` without its Jacobian (the Runge–Kutta
    /// stages that need only f); `scratch` (≥ `dim()` long) receives the effects' partials.
    pub fn angle_rate_value(
        &self,
        x: &[f64],
        t_s: f64,
        temp_dev_c: f64,
        scratch: &mut [Vector3<f64>],
    ) -> Vector3<f64> {
        self.rate(x, t_s, temp_dev_c, scratch, false)
    }

    /// θ̇, and F's angle rows into `d_dx` when `jacobian` (otherwise `d_dx[3..]` receives the
    /// effects' partials only). One body for both: the firmware's flash.
    #[inline(never)]
    fn rate(
        &self,
        x: &[f64],
        t_s: f64,
        temp_dev_c: f64,
        d_dx: &mut [Vector3<f64>],
        jacobian: bool,
    ) -> Vector3<f64> {
        let n = self.dim();
        let att = Attitude::new(&Vector3::new(x[0], x[1], x[2]));
        let ctx = self.context(&att, t_s, temp_dev_c);
        let (drift_degph, d_force) = self.effect_terms(x, &ctx, d_dx, true);
        let k = rate_to_euler(&att);
        let we0 = self.earth_rate_r;
        let c_we0 = att.c * we0;
        let w = drift_degph * RADPS_PER_DEGPH - c_we0;
        let rate = k * w;
        if !jacobian {
            return rate;
        }
        let k_deg = k * RADPS_PER_DEGPH;
        for col in d_dx[ANGLES..n].iter_mut() {
            // Most parameters drive one gyro axis: K's column times that entry (the full
            // product adds only zeros to it).
            match (col.x != 0.0, col.y != 0.0, col.z != 0.0) {
                (false, false, false) => {}
                (true, false, false) => *col = k_deg.column(0) * col.x,
                (false, true, false) => *col = k_deg.column(1) * col.y,
                (false, false, true) => *col = k_deg.column(2) * col.z,
                _ => *col = k_deg * *col,
            }
        }
        let dk = d_rate_to_euler(&att, &w);
        let g = self.gravity_r;
        // ∂A/∂θ_j and ∂(C·w_e0)/∂θ_j from A = C·g and C·w_e0 (see `d_rotated`).
        let da = d_rotated(&att, &ctx.specific_force, &g);
        let dwe = d_rotated(&att, &c_we0, &we0);
        let d_force_rad = d_force * RADPS_PER_DEGPH;
        for j in 0..ANGLES {
            let dw = d_force_rad * da[j] - dwe[j];
            d_dx[j] = dk[j] + k * dw;
        }
        if self.uses_north() {
            self.add_through_north(x, &att, &ctx, Some(&k_deg), d_dx);
        }
        rate
    }

    /// Predicted accelerometer output h(x) (m/s², platform axes) and its Jacobian
    /// `d_dx[j] = ∂h/∂x_j` (zero except for the angles and accelerometer-effect parameters).
    ///
    /// `time_var_s2` is the spread of the averaged samples' times about `t_s` (see
    /// [`crate::Measurement::time_var_s2`]): the mean of A over the window exceeds A(t_s) by
    /// ½·Var(t)·Ä, and for the platform at rest Ä = ω×(ω×A) = C·(w_e0×(w_e0×g0)) (the cross
    /// product commutes with the rotation), about 6e-6 m/s² for 60-s windows of 1-s samples —
    /// small, but systematic: without it the residual looks like a ~0.8 ppm scale-factor error.
    pub fn measurement(
        &self,
        x: &[f64],
        t_s: f64,
        temp_dev_c: f64,
        time_var_s2: f64,
        d_dx: &mut [Vector3<f64>],
    ) -> Vector3<f64> {
        let att = Attitude::new(&Vector3::new(x[0], x[1], x[2]));
        let ctx = self.context(&att, t_s, temp_dev_c);
        let (error, d_force) = self.effect_terms(x, &ctx, d_dx, false);
        let g = self.gravity_r;
        let d_total = Matrix3::identity() + d_force;
        let we0 = self.earth_rate_r;
        let curvature_0 = we0.cross(&we0.cross(&g)) * (0.5 * time_var_s2);
        let c_curv = att.c * curvature_0;
        let da = d_rotated(&att, &ctx.specific_force, &g);
        let dcurv = d_rotated(&att, &c_curv, &curvature_0);
        for j in 0..ANGLES {
            d_dx[j] = d_total * da[j] + dcurv[j];
        }
        if self.uses_north() {
            self.add_through_north(x, &att, &ctx, None, d_dx);
        }
        ctx.specific_force + error + c_curv
    }
}

/// `∂(C·v)/∂θ_j` for j = x, y, z (v fixed), from `cv = C·v`: with `C = Rz·Ry·Rx` (passive
/// elementary rotations, [`Attitude`]), ∂C/∂tx = −C·[e_x]×, ∂C/∂ty = −[u]×·C with
/// u = Rz·e_y = (sin tz, cos tz, 0), and ∂C/∂tz = −[e_z]×·C. So only ∂/∂tx needs a product
/// with C (of v × e_x = (0, v_z, −v_y)); the others are cross products with `cv`. Cheaper than
/// the three matrices ∂C/∂θ_j times v; checked against finite differences by the model's
/// Jacobian tests.
fn d_rotated(att: &Attitude, cv: &Vector3<f64>, v: &Vector3<f64>) -> [Vector3<f64>; 3] {
    let (sz, cz) = (att.sin.z, att.cos.z);
    [
        att.c.column(1) * v.z - att.c.column(2) * v.y,
        Vector3::new(-cz * cv.z, sz * cv.z, cz * cv.x - sz * cv.y),
        Vector3::new(cv.y, -cv.x, 0.0),
    ]
}
