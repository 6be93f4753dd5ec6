//! Analytic F, H and Φ against central finite differences.
//!
//! Tolerances: central differences with step h have truncation error O(h²·f''') and rounding
//! error O(ε·f/h). With h = 1e-6 (angles, rad) and 1e-4 (coefficients, unit-scaled) both are
//! below 1e-7 relative to the column's scale, so a 1e-6 relative tolerance catches any wrong term
//! (a missing or wrong-sign term changes a column by O(1) relative).

use estimator_core::effects::{
    AccBias, AccMisalign, AccScale, AccTemp, DriftDaily, DriftMarkov, DriftTrend, Effect, G2Drift,
    PaperDrift, Partials, TempDrift,
};
use estimator_core::model::{Model, Propagation};
use estimator_core::propagate::{propagate, Transition};
use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::Site;
use nalgebra::{Matrix3, Vector3};

const CAP: usize = 64;

static MARKOV: DriftMarkov = DriftMarkov {
    sigma_degph: 0.01,
    tau_h: 2.0,
};
/// Every catalog effect at once, so each effect's partials are checked.
static EFFECTS: [&dyn Effect; 10] = [
    &PaperDrift,
    &AccBias,
    &MARKOV,
    &G2Drift,
    &AccScale,
    &AccMisalign,
    &DriftTrend::CATALOG,
    &TempDrift::CATALOG,
    &AccTemp,
    &DriftDaily { sigma_degph: 0.01 },
];

fn model(propagation: Propagation) -> Model<'static> {
    Model::new(
        Site::new(39.1, None),
        &EFFECTS,
        arw_deg2ph_to_rad2ps(1e-8),
        propagation,
    )
    .unwrap()
}

/// A state far from zero: large angles and coefficients (a few times the paper's values), so
/// every term of the Jacobians is exercised.
fn test_state(m: &Model<'_>, k: usize) -> Vec<f64> {
    let mut x = vec![0.0; m.dim()];
    let angles = [[0.3, -0.7, 2.1], [-1.1, 0.45, -2.8], [0.05, 0.9, 0.6]][k];
    x[..3].copy_from_slice(&angles);
    for (i, v) in x.iter_mut().enumerate().skip(3) {
        *v = ((i * 7919 + k * 104729) % 17) as f64 / 17.0 - 0.5;
    }
    x
}

fn step_for(i: usize) -> f64 {
    if i < 3 {
        1e-6
    } else {
        1e-4
    }
}

fn assert_columns_close(name: &str, analytic: &[Vector3<f64>], numeric: &[Vector3<f64>]) {
    let scale = numeric.iter().map(|c| c.amax()).fold(0.0, f64::max);
    for (j, (a, n)) in analytic.iter().zip(numeric).enumerate() {
        let err = (a - n).amax();
        assert!(
            err <= 1e-6 * scale.max(n.amax()),
            "{name} column {j}: analytic {a:?} vs numeric {n:?}"
        );
    }
}

#[test]
fn angle_rate_jacobian_matches_finite_differences() {
    let m = model(Propagation::default());
    for k in 0..3 {
        let x = test_state(&m, k);
        let mut jac = [Vector3::zeros(); CAP];
        m.angle_rate(&x, 3600.0, 0.4, &mut jac);
        let mut scratch = [Vector3::zeros(); CAP];
        let numeric: Vec<_> = (0..m.dim())
            .map(|j| {
                let h = step_for(j);
                let (mut xp, mut xm) = (x.clone(), x.clone());
                xp[j] += h;
                xm[j] -= h;
                (m.angle_rate(&xp, 3600.0, 0.4, &mut scratch)
                    - m.angle_rate(&xm, 3600.0, 0.4, &mut scratch))
                    / (2.0 * h)
            })
            .collect();
        assert_columns_close("F", &jac[..m.dim()], &numeric);
    }
}

#[test]
fn measurement_jacobian_matches_finite_differences() {
    let m = model(Propagation::default());
    for k in 0..3 {
        let x = test_state(&m, k);
        let mut jac = [Vector3::zeros(); CAP];
        m.measurement(&x, 3600.0, 0.7, 300.0, &mut jac);
        let mut scratch = [Vector3::zeros(); CAP];
        let numeric: Vec<_> = (0..m.dim())
            .map(|j| {
                let h = step_for(j);
                let (mut xp, mut xm) = (x.clone(), x.clone());
                xp[j] += h;
                xm[j] -= h;
                (m.measurement(&xp, 3600.0, 0.7, 300.0, &mut scratch)
                    - m.measurement(&xm, 3600.0, 0.7, 300.0, &mut scratch))
                    / (2.0 * h)
            })
            .collect();
        assert_columns_close("H", &jac[..m.dim()], &numeric);
        for j in 0..m.dim() {
            if !m.is_measured(j) {
                assert_eq!(
                    jac[j],
                    Vector3::zeros(),
                    "H column {j} must be structurally zero"
                );
            }
        }
    }
}

/// Φ over one 60-s period of `prop` against central differences of the propagated state at
/// test state `k`: for each column j, the largest |analytic − numeric| over the rows, relative
/// to the column's scale max_i |Φ[i][j] − δ_ij| (how far the period moves the state).
fn transition_errors(prop: Propagation, k: usize) -> Vec<f64> {
    let m = model(prop);
    let n = m.dim();
    let x = test_state(&m, k);
    let mut tr = Transition::<CAP>::default();
    let mut x1 = x.clone();
    propagate(&m, &mut x1, 100.0, 60.0, 0.1, 0.3, &mut tr);
    let mut scratch = Transition::<CAP>::default();
    (0..n)
        .map(|j| {
            let h = step_for(j);
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[j] += h;
            xm[j] -= h;
            propagate(&m, &mut xp, 100.0, 60.0, 0.1, 0.3, &mut scratch);
            propagate(&m, &mut xm, 100.0, 60.0, 0.1, 0.3, &mut scratch);
            let (mut err, mut scale) = (0.0_f64, 0.0_f64);
            for i in 0..n {
                let numeric = (xp[i] - xm[i]) / (2.0 * h);
                let delta = f64::from(u8::from(i == j));
                // Rounding: the propagated x_i (|x_i| ≤ 3) carry ε·|x_i| each, so the
                // difference quotient carries ~2ε·|x_i|/h absolute; discounted here.
                let rounding = 4.0 * f64::EPSILON * x1[i].abs().max(1.0) / h;
                err = err.max(((numeric - tr.phi_entry(&m, i, j)).abs() - rounding).max(0.0));
                scale = scale.max((numeric - delta).abs());
            }
            err / scale
        })
        .collect()
}

/// Φ over one 60-s period against differences of the propagated state.
///
/// Euler: Φ = I + F·dt is the exact derivative of its map, so the differences' own truncation
/// (1e-7 relative, module doc) is the tolerance. RK4: Φ is the exponential of F at the
/// sub-step's midpoint (`propagate`'s doc), not the derivative of the Runge–Kutta map; they
/// differ by the Magnus truncation. For a column whose F entry changes by a fraction ν over a
/// sub-step that turns the state by ρ = ‖h·F_DD‖ that is ρ·ν/12 of the column (plus ν²/24-order
/// terms). These test states are extreme on purpose: the temperature deviation triples within
/// the period (ν ≈ 1 for the temperature columns), coefficients of ±0.5 in their units (up to
/// ~50 deg/h of drift, ρ ≈ 1e-2): the error reaches 2.7e-3 of a column at 60 s (the paper's
/// model at the paper's coefficients: 1e-5). The tolerance, 5e-3·(h/60 s)², is that bound with
/// room and the scheme's h² scaling; a wrong or missing term in Φ changes its column by O(1).
/// (Ψ = h·I, a first-order slip of ρ/2 ≈ 5e-3, is caught by the next test.)
#[test]
fn transition_matrix_matches_finite_differences() {
    for (prop, tol) in [
        (Propagation::Euler, 1e-7),
        (Propagation::default(), 5e-3),
        (Propagation::Rk4 { max_step_s: 20.0 }, 5e-3 / 9.0),
    ] {
        for k in 0..3 {
            let errors = transition_errors(prop, k);
            let worst = errors.iter().copied().fold(0.0, f64::max);
            assert!(
                worst <= tol,
                "{prop:?} state {k}: Φ column error {worst:.2e} > {tol:.1e}"
            );
        }
    }
}

/// The midpoint exponential is a second-order scheme: with sub-steps a third as long, Φ's
/// error against the map's derivative falls 9-fold (global error ∝ h²; measured 8.99–9.02). A
/// first-order slip (F taken at a stage's start, or Ψ = h·I) would fall 3-fold, a wrong term
/// not at all. The band 7.5–10.5 leaves room for the O(h³) terms.
#[test]
fn transition_matrix_error_is_second_order_in_the_sub_step() {
    for k in 0..3 {
        let worst = |max_step_s| {
            transition_errors(Propagation::Rk4 { max_step_s }, k)
                .into_iter()
                .fold(0.0, f64::max)
        };
        let (coarse, fine) = (worst(60.0), worst(20.0));
        let ratio = coarse / fine;
        assert!(
            (7.5..10.5).contains(&ratio),
            "state {k}: error {coarse:.2e} at 60 s, {fine:.2e} at 20 s: ratio {ratio:.2}"
        );
    }
}

/// The paper's kinematics: with zero drift, θ̇ = K(θ)(−C w_e0) keeps the platform fixed in inertial
/// space, so after one sidereal day the platform is back at θ = 0 (RK4, 60-s steps).
#[test]
fn zero_drift_platform_returns_after_one_sidereal_day() {
    let m = model(Propagation::default());
    let mut x = vec![0.0; m.dim()];
    let mut tr = Transition::<CAP>::default();
    let sidereal_day = 2.0 * core::f64::consts::PI / estimator_core::units::EARTH_RATE_RADPS;
    let steps = 1436;
    let dt = sidereal_day / steps as f64;
    let mut max_ty: f64 = 0.0;
    for k in 0..steps {
        propagate(&m, &mut x, k as f64 * dt, dt, 0.0, 0.0, &mut tr);
        max_ty = max_ty.max(x[1].abs());
    }
    let wrap = |a: f64| {
        (a + core::f64::consts::PI).rem_euclid(2.0 * core::f64::consts::PI) - core::f64::consts::PI
    };
    // RK4 global error over 1436 steps of 60 s at Earth rate: ~(ωh)^4·ωT ≈ 1e-9 rad.
    for i in 0..3 {
        assert!(
            wrap(x[i]).abs() < 1e-8,
            "θ[{i}] = {} after a sidereal day",
            x[i]
        );
    }
    // |sin ty| ≤ cos L on the cone about the polar axis.
    let lat = 39.1f64.to_radians();
    assert!(max_ty.sin() <= lat.cos() + 1e-9 && max_ty > 0.5 * lat.cos().asin());
}

/// The multiplied-out C equals the product of the elementary rotations of model.md.
#[test]
fn attitude_is_rz_ry_rx() {
    use estimator_core::frames::Attitude;
    use nalgebra::Matrix3;
    let rx = |a: f64| Matrix3::new(1.0, 0.0, 0.0, 0.0, a.cos(), a.sin(), 0.0, -a.sin(), a.cos());
    let ry = |a: f64| Matrix3::new(a.cos(), 0.0, -a.sin(), 0.0, 1.0, 0.0, a.sin(), 0.0, a.cos());
    let rz = |a: f64| Matrix3::new(a.cos(), a.sin(), 0.0, -a.sin(), a.cos(), 0.0, 0.0, 0.0, 1.0);
    for theta in [Vector3::new(0.3, -0.7, 2.1), Vector3::new(-1.1, 0.45, -2.8)] {
        let att = Attitude::new(&theta);
        let c = rz(theta.z) * ry(theta.y) * rx(theta.x);
        assert!((att.c - c).amax() < 1e-15, "C differs from Rz·Ry·Rx");
        for j in 0..3 {
            let h = 1e-6;
            let mut tp = theta;
            let mut tm = theta;
            tp[j] += h;
            tm[j] -= h;
            let num = (Attitude::new(&tp).c - Attitude::new(&tm).c) / (2.0 * h);
            // Central-difference truncation h²/6 ≈ 2e-13, rounding ε/h ≈ 2e-10.
            assert!((att.dc()[j] - num).amax() < 1e-9, "∂C/∂θ{j}");
        }
    }
}

/// A test effect that depends on north (`Context::north`) nonlinearly, on every axis, so every
/// entry of ∂value/∂north and its chain to the angles is exercised: drift (deg/h) or
/// accelerometer error (m/s²) `[k0·n_x·n_y, k1·n_z·A_x, k2·n_x²]`.
struct NorthTerm {
    accel: bool,
}

static NORTH_PARAMS: [estimator_core::effects::Param; 3] = [
    estimator_core::effects::Param {
        name: "N0",
        unit: "1",
        prior_sigma: 0.1,
    },
    estimator_core::effects::Param {
        name: "N1",
        unit: "1",
        prior_sigma: 0.1,
    },
    estimator_core::effects::Param {
        name: "N2",
        unit: "1",
        prior_sigma: 0.1,
    },
];

impl NorthTerm {
    fn add(&self, p: &[f64], ctx: &estimator_core::effects::Context, out: Partials<'_>) {
        let (n, a) = (ctx.north, ctx.specific_force);
        *out.value += Vector3::new(p[0] * n.x * n.y, p[1] * n.z * a.x, p[2] * n.x * n.x);
        out.d_params[0] = Vector3::new(n.x * n.y, 0.0, 0.0);
        out.d_params[1] = Vector3::new(0.0, n.z * a.x, 0.0);
        out.d_params[2] = Vector3::new(0.0, 0.0, n.x * n.x);
        out.d_force[(1, 0)] += p[1] * n.z;
    }
    fn north_partials(
        &self,
        p: &[f64],
        ctx: &estimator_core::effects::Context,
        d: &mut Matrix3<f64>,
    ) {
        let (n, a) = (ctx.north, ctx.specific_force);
        d[(0, 0)] += p[0] * n.y;
        d[(0, 1)] += p[0] * n.x;
        d[(1, 2)] += p[1] * a.x;
        d[(2, 0)] += 2.0 * p[2] * n.x;
    }
}

impl Effect for NorthTerm {
    fn name(&self) -> &'static str {
        if self.accel {
            "test-acc-north"
        } else {
            "test-drift-north"
        }
    }
    fn about(&self) -> &'static str {
        "test only"
    }
    fn params(&self) -> &[estimator_core::effects::Param] {
        &NORTH_PARAMS
    }
    fn drift(&self, p: &[f64], ctx: &estimator_core::effects::Context, out: Partials<'_>) {
        self.add(p, ctx, out);
    }
    fn accel_error(&self, p: &[f64], ctx: &estimator_core::effects::Context, out: Partials<'_>) {
        self.add(p, ctx, out);
    }
    fn touches_drift(&self) -> bool {
        !self.accel
    }
    fn touches_accel(&self) -> bool {
        self.accel
    }
    fn uses_north(&self) -> bool {
        true
    }
    fn d_north(
        &self,
        p: &[f64],
        ctx: &estimator_core::effects::Context,
        drift: bool,
        d: &mut Matrix3<f64>,
    ) {
        if drift != self.accel {
            self.north_partials(p, ctx, d);
        }
    }
}

/// A function of the state (with scratch space for the effects' partials), for differences.
type StateFn<'a> = dyn FnMut(&[f64], &mut [Vector3<f64>]) -> Vector3<f64> + 'a;

static NORTH_EFFECTS: [&dyn Effect; 3] = [
    &PaperDrift,
    &NorthTerm { accel: false },
    &NorthTerm { accel: true },
];

/// F and H of a model whose effects depend on north match central differences, in both charts
/// (north = C·R·[0, 1, 0]; the polar chart's R is not the identity). Tolerance as in the module
/// doc: 1e-6 of the column's scale.
#[test]
fn north_dependent_effects_jacobians_match_finite_differences() {
    use estimator_core::frames::Chart;
    for chart in [Chart::Enu, Chart::Polar] {
        let mut site = Site::new(39.1, None);
        site.chart = chart;
        let m = Model::new(
            site,
            &NORTH_EFFECTS,
            arw_deg2ph_to_rad2ps(1e-8),
            Propagation::default(),
        )
        .unwrap();
        for k in 0..3 {
            let x = test_state(&m, k);
            let mut scratch = [Vector3::zeros(); CAP];
            let mut numeric = |f: &mut StateFn<'_>| {
                (0..m.dim())
                    .map(|j| {
                        let h = step_for(j);
                        let (mut xp, mut xm) = (x.clone(), x.clone());
                        xp[j] += h;
                        xm[j] -= h;
                        (f(&xp, &mut scratch) - f(&xm, &mut scratch)) / (2.0 * h)
                    })
                    .collect::<Vec<_>>()
            };
            let mut jac = [Vector3::zeros(); CAP];
            m.angle_rate(&x, 3600.0, 0.4, &mut jac);
            let num = numeric(&mut |x, s| m.angle_rate(x, 3600.0, 0.4, s));
            assert_columns_close(&format!("F ({chart:?})"), &jac[..m.dim()], &num);
            m.measurement(&x, 3600.0, 0.7, 300.0, &mut jac);
            let num = numeric(&mut |x, s| m.measurement(x, 3600.0, 0.7, 300.0, s));
            assert_columns_close(&format!("H ({chart:?})"), &jac[..m.dim()], &num);
        }
    }
}

/// North is C_0^p·[0, 1, 0] in either chart: at the same physical attitude (ENU angles θ, their
/// polar-chart angles from `angles_to_chart`) both models give the same north, a unit vector
/// orthogonal to A (exact up to rounding of a few products: 1e-14).
#[test]
fn north_is_the_same_unit_vector_in_both_charts_and_orthogonal_to_up() {
    use estimator_core::frames::{Attitude, Chart};
    let mut polar = Site::new(39.1, None);
    polar.chart = Chart::Polar;
    let enu = Site::new(39.1, None);
    let theta_enu = [0.3, -0.7, 2.1];
    let theta_r = polar.angles_to_chart(&theta_enu);
    let c_enu = Attitude::new(&Vector3::from(theta_enu)).c;
    let c_r = Attitude::new(&Vector3::from(theta_r)).c;
    let (n1, n2) = (c_enu * enu.north_r(), c_r * polar.north_r());
    assert!((n1 - n2).amax() < 1e-14, "{n1:?} vs {n2:?}");
    assert!((n1.norm() - 1.0).abs() < 1e-14);
    assert!(n1.dot(&(c_enu * enu.gravity_r())).abs() < 1e-13);
    // Column 1 of C_0^p (frame 0 is ENU: its y axis is north).
    assert!((n1 - c_enu.column(1)).amax() < 1e-15);
}
