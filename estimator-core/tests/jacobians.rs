//! Analytic F, H and Φ against central finite differences.
//!
//! Tolerances: central differences with step h have truncation error O(h²·f''') and rounding
//! error O(ε·f/h). With h = 1e-6 (angles, rad) and 1e-4 (coefficients, unit-scaled) both are
//! below 1e-7 relative to the column's scale, so a 1e-6 relative tolerance catches any wrong term
//! (a missing or wrong-sign term changes a column by O(1) relative).

use estimator_core::effects::{
    AccBias, AccMisalign, AccScale, DriftMarkov, DriftTrend, Effect, G2Drift, PaperDrift, TempDrift,
};
use estimator_core::model::{Model, Propagation};
use estimator_core::propagate::{propagate, Transition};
use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::Site;
use nalgebra::Vector3;

const CAP: usize = 64;

static MARKOV: DriftMarkov = DriftMarkov {
    sigma_degph: 0.01,
    tau_h: 2.0,
};
/// Every catalog effect at once, so each effect's partials are checked.
static EFFECTS: [&dyn Effect; 8] = [
    &PaperDrift,
    &AccBias,
    &MARKOV,
    &G2Drift,
    &AccScale,
    &AccMisalign,
    &DriftTrend,
    &TempDrift,
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
        m.measurement(&x, 0.0, 0.0, 300.0, &mut jac);
        let mut scratch = [Vector3::zeros(); CAP];
        let numeric: Vec<_> = (0..m.dim())
            .map(|j| {
                let h = step_for(j);
                let (mut xp, mut xm) = (x.clone(), x.clone());
                xp[j] += h;
                xm[j] -= h;
                (m.measurement(&xp, 0.0, 0.0, 300.0, &mut scratch)
                    - m.measurement(&xm, 0.0, 0.0, 300.0, &mut scratch))
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

/// Φ over one 60-s period (RK4 and Euler) against differences of the propagated state.
#[test]
fn transition_matrix_matches_finite_differences() {
    for prop in [
        Propagation::default(),
        Propagation::Euler,
        Propagation::Rk4 { max_step_s: 20.0 },
    ] {
        let m = model(prop);
        let n = m.dim();
        let x = test_state(&m, 0);
        let mut tr = Transition::<CAP>::default();
        let mut x1 = x.clone();
        propagate(&m, &mut x1, 100.0, 60.0, 0.1, 0.3, &mut tr);
        let mut scratch = Transition::<CAP>::default();
        for j in 0..n {
            let h = step_for(j);
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[j] += h;
            xm[j] -= h;
            propagate(&m, &mut xp, 100.0, 60.0, 0.1, 0.3, &mut scratch);
            propagate(&m, &mut xm, 100.0, 60.0, 0.1, 0.3, &mut scratch);
            for i in 0..n {
                let numeric = (xp[i] - xm[i]) / (2.0 * h);
                let analytic = tr.phi_entry(&m, i, j);
                // Truncation: 1e-7 relative. Rounding: the propagated x_i (|x_i| ≤ 3) carry
                // ε·|x_i| each, so the difference quotient carries ~2ε·|x_i|/h absolute.
                let rounding = 4.0 * f64::EPSILON * x1[i].abs().max(1.0) / h;
                let tol = 1e-7 * numeric.abs() + rounding;
                assert!(
                    (numeric - analytic).abs() <= tol,
                    "{prop:?} Φ[{i}][{j}]: analytic {analytic} vs numeric {numeric}"
                );
            }
        }
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
