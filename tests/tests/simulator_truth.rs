//! The truth simulator against closed forms and model.md's kinematics (formulas written out
//! here, independently of both the simulator and the estimator core).

#![allow(clippy::needless_range_loop, clippy::type_complexity)]

use std::f64::consts::PI;

use host_tool::simulate::{
    read_truth, simulate, write_simulation, InjectedEffect, Scenario, Simulator,
};
use nalgebra::{Matrix3, Vector3};

const OMEGA: f64 = 7.292115e-5;
const DEG_H: f64 = PI / 180.0 / 3600.0;

fn rx(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, s, 0.0, -s, c)
}

/// exp(−[φ×]) by its power series (not Rodrigues' closed form), summed to convergence.
fn exp_minus_skew(phi: &Vector3<f64>) -> Matrix3<f64> {
    let k = -Matrix3::new(0.0, -phi.z, phi.y, phi.z, 0.0, -phi.x, -phi.y, phi.x, 0.0);
    let mut term = Matrix3::identity();
    let mut sum = Matrix3::identity();
    for n in 1..60 {
        term = term * k / n as f64;
        sum += term;
    }
    sum
}

/// Euler angles of C = Rz(tz)·Ry(ty)·Rx(tx) (model.md).
fn euler(c: &Matrix3<f64>) -> Vector3<f64> {
    Vector3::new(
        (-c[(2, 1)]).atan2(c[(2, 2)]),
        c[(2, 0)].asin(),
        (-c[(1, 0)]).atan2(c[(0, 0)]),
    )
}

fn wrap(a: f64) -> f64 {
    (a + PI).rem_euclid(2.0 * PI) - PI
}

/// A noise-free scenario with the given coefficients and effects.
fn quiet(
    coefficients: [f64; 12],
    effects: Vec<InjectedEffect>,
    hours: f64,
    rate_s: f64,
) -> Scenario {
    let mut s = Scenario::paper().without_noise();
    s.coefficients = coefficients;
    s.effects = effects;
    s.hours = hours;
    s.rate_s = rate_s;
    s
}

fn lat() -> f64 {
    39.1f64.to_radians()
}

#[test]
fn without_drift_the_specific_force_traces_the_cone_and_returns_after_a_sidereal_day() {
    let s = quiet([0.0; 12], vec![], 24.0, 60.0);
    let g = s.gravity();
    let n = Vector3::new(0.0, lat().cos(), lat().sin());
    let sim = simulate(&s);
    for smp in &sim.samples {
        let a = Vector3::from(smp.specific_force_mps2);
        assert!(
            (n.dot(&a) - g * lat().sin()).abs() < 1e-12 * g,
            "t = {}",
            smp.t_s
        );
        assert!((a.norm() - g).abs() < 1e-12 * g);
    }
    // Half a sidereal day: A is the reflection of [0, 0, g] through the polar axis.
    let mut sm = Simulator::new(&s);
    let day = 2.0 * PI / OMEGA; // 86164.0989 s
    sm.advance_to(0.5 * day, 1.0);
    let mirrored = n * (2.0 * g * lat().sin()) - Vector3::new(0.0, 0.0, g);
    assert!((sm.specific_force() - mirrored).norm() < 1e-9);
    sm.advance_to(day, 1.0);
    let err = (sm.specific_force() - Vector3::new(0.0, 0.0, g)).norm();
    assert!(err < 1e-9, "after 2π/Ω: |A − g0| = {err:e}");
    // 2π/Ω = 86164.1006 s with Ω = 7.292115e-5 rad/s; at the rounded 86164.1 s the Earth lacks
    // 4.6e-8 rad of a full turn, which leaves A off by g·cos L·Ω·Δt ≈ 3.5e-7 m/s², far above
    // 1e-9. The simulator gets that right too.
    let mut sm = Simulator::new(&s);
    sm.advance_to(86164.1, 1.0);
    let err = (sm.specific_force() - Vector3::new(0.0, 0.0, g)).norm();
    let expect = g * lat().cos() * OMEGA * (day - 86164.1);
    assert!(
        (err / expect - 1.0).abs() < 1e-3,
        "err {err:e}, expected {expect:e}"
    );
}

/// w_d = C·w_e0 + M(θ)·θ̇ (model.md) by central differences of θ extracted from the simulator's
/// C_0^p, against the drift rate the model prescribes, `drift(A, t)` (rad/s).
fn check_kinematics(
    s: &Scenario,
    times_h: &[f64],
    drift: impl Fn(&Vector3<f64>, f64) -> Vector3<f64>,
) {
    let we0 = Vector3::new(0.0, OMEGA * lat().cos(), OMEGA * lat().sin());
    let h = 1.0;
    let mut sm = Simulator::new(s);
    for &th in times_h {
        let t = th * 3600.0;
        sm.advance_to(t - h, 1.0);
        let e1 = euler(&sm.c_0p());
        sm.advance_to(t, 1.0);
        let c = sm.c_0p();
        let e0 = euler(&c);
        let a = sm.specific_force();
        sm.advance_to(t + h, 1.0);
        let e2 = euler(&sm.c_0p());
        let d = Vector3::new(wrap(e2.x - e1.x), e2.y - e1.y, wrap(e2.z - e1.z)) / (2.0 * h);
        let (sy, cy) = e0.y.sin_cos();
        let (sz, cz) = e0.z.sin_cos();
        let m = Matrix3::new(cy * cz, sz, 0.0, -cy * sz, cz, 0.0, sy, 0.0, 1.0);
        let w_kin = c * we0 + m * d;
        let w_model = drift(&a, t);
        // Truncation of the central difference ~ Ω³h² ≈ 4e-13 rad/s; drifts are ~1e-6 rad/s.
        let err = (w_kin - w_model).norm();
        assert!(
            err < 1e-11 && err < 1e-4 * w_model.norm(),
            "t = {th} h: kinematic {w_kin:?} vs model {w_model:?} (err {err:e})"
        );
    }
}

fn paper_drift(c: &[f64; 12], a: &Vector3<f64>) -> Vector3<f64> {
    Vector3::from_fn(|i, _| {
        (c[4 * i] + c[4 * i + 1] * a.x + c[4 * i + 2] * a.y + c[4 * i + 3] * a.z) * DEG_H
    })
}

#[test]
fn constant_drift_satisfies_the_kinematic_relation_and_the_closed_form() {
    let mut coeff = [0.0; 12];
    coeff[0] = 0.5;
    coeff[4] = -0.5;
    coeff[8] = 0.5;
    let s = quiet(coeff, vec![], 0.0, 1.0);
    let w = Vector3::new(0.5, -0.5, 0.5) * DEG_H;
    check_kinematics(&s, &[0.5, 3.0, 11.0, 20.0], |_, _| w);
    // Constant w_d: C_i^p(t) = exp(−[w t×]) exactly.
    let mut sm = Simulator::new(&s);
    let t = 30.0 * 3600.0;
    sm.advance_to(t, 1.0);
    let err = (sm.c_ip() - exp_minus_skew(&(w * t))).norm();
    assert!(err < 1e-12, "C_i^p off the closed form by {err:e}");
}

#[test]
fn paper_drift_satisfies_the_kinematic_relation() {
    let s = quiet(Scenario::paper().coefficients, vec![], 0.0, 1.0);
    let c = s.coefficients;
    check_kinematics(&s, &[0.25, 6.0, 17.0, 29.0], |a, _| paper_drift(&c, a));
}

#[test]
fn g2_drift_satisfies_the_kinematic_relation() {
    let mut d = [[0.0; 6]; 3];
    d[0] = [0.002, 0.0, 0.0, 0.0, 0.0, 0.001];
    d[1] = [0.0, 0.003, 0.0, 0.0, 0.0, -0.002];
    d[2] = [0.0, 0.0, 0.001, 0.002, 0.001, 0.0005];
    let s = quiet(
        Scenario::paper().coefficients,
        vec![InjectedEffect::G2 {
            d_deg_h_per_mps2_sq: d,
        }],
        0.0,
        1.0,
    );
    let c = s.coefficients;
    check_kinematics(&s, &[0.5, 8.0, 19.0], |a, _| {
        let p = [
            a.x * a.x,
            a.x * a.y,
            a.x * a.z,
            a.y * a.y,
            a.y * a.z,
            a.z * a.z,
        ];
        paper_drift(&c, a)
            + Vector3::from_fn(|i, _| (0..6).map(|k| d[i][k] * p[k]).sum::<f64>() * DEG_H)
    });
}

#[test]
fn drift_trend_integrates_to_k_t_squared_over_two() {
    // Zero coefficients, w_d = k·t/3600 deg/h: the direction is fixed, so the platform turns
    // about k by |k|·t²/7200 (deg/h·s → rad via DEG_H).
    let k = Vector3::new(0.1, -0.2, 0.3);
    let s = quiet(
        [0.0; 12],
        vec![InjectedEffect::DriftTrend {
            k_deg_h_per_h: k.into(),
        }],
        0.0,
        1.0,
    );
    let mut sm = Simulator::new(&s);
    for th in [2.0, 10.0, 25.0] {
        let t: f64 = th * 3600.0;
        sm.advance_to(t, 1.0);
        let phi = k * DEG_H * t * t / 7200.0;
        let err = (sm.c_ip() - exp_minus_skew(&phi)).norm();
        assert!(
            err < 1e-12,
            "t = {th} h: err {err:e} (angle {:e})",
            phi.norm()
        );
    }
    check_kinematics(&s, &[1.0, 12.0], |_, t| k * DEG_H * t / 3600.0);
}

#[test]
fn temp_drift_follows_the_temperature_profile() {
    // Single axis x: C_i^p = Rx(∫ c (T − T0) dt) with T − T0 = 0.8 sin(2π t/30h) + 0.3 (1 − e^{−t/5h}).
    let cx = 0.05;
    let s = quiet(
        [0.0; 12],
        vec![InjectedEffect::TempDrift {
            c_deg_h_per_c: [cx, 0.0, 0.0],
        }],
        0.0,
        1.0,
    );
    let mut sm = Simulator::new(&s);
    for th in [3.0, 20.0] {
        sm.advance_to(th * 3600.0, 1.0);
        let (p, tau) = (30.0, 5.0);
        let integral_c_h = 0.8 * p / (2.0 * PI) * (1.0 - (2.0 * PI * th / p).cos())
            + 0.3 * (th - tau * (1.0 - (-th / tau).exp()));
        let angle = cx * DEG_H * integral_c_h * 3600.0;
        let err = (sm.c_ip() - rx(angle)).norm();
        assert!(
            err < 1e-9 * angle.abs(),
            "t = {th} h: err {err:e} vs angle {angle:e}"
        );
    }
    // The file gets a temp_c column: the profile plus 0.01 °C white noise.
    let mut s = s.clone();
    s.temp_profile.noise_c = 0.01;
    s.hours = 2.0;
    let sim = simulate(&s);
    let res: Vec<f64> = sim
        .samples
        .iter()
        .map(|x| x.temp_c.unwrap() - s.temp_profile.at(x.t_s))
        .collect();
    let n = res.len() as f64;
    let mean = res.iter().sum::<f64>() / n;
    let sd = (res.iter().map(|r| (r - mean) * (r - mean)).sum::<f64>() / n).sqrt();
    assert!(mean.abs() < 5.0 * 0.01 / n.sqrt(), "mean {mean}");
    assert!((sd / 0.01 - 1.0).abs() < 0.05, "sd {sd}"); // 7201 samples: 1σ ≈ 0.8 %
                                                        // Without temp-drift and without write_temp there is no column.
    assert!(simulate(&quiet([0.0; 12], vec![], 0.01, 1.0)).samples[0]
        .temp_c
        .is_none());
}

#[test]
fn drift_markov_has_its_std_and_correlation_time_and_drives_the_attitude() {
    let (sigma, tau_h) = (0.05, 0.1);
    let s = quiet(
        [0.0; 12],
        vec![InjectedEffect::DriftMarkov {
            sigma_deg_h: [sigma, 0.0, 0.0],
            tau_h: [tau_h, 1.0, 1.0],
        }],
        0.0,
        1.0,
    );
    let mut sm = Simulator::new(&s);
    let hours = 50.0;
    let n = (hours * 3600.0) as usize;
    let mut m = Vec::with_capacity(n + 1);
    let mut angle = 0.0;
    let mut prev = sm.markov_rad_s()[0];
    m.push(prev);
    for i in 1..=n {
        sm.advance_to(i as f64, 1.0);
        let cur = sm.markov_rad_s()[0];
        angle += 0.5 * (prev + cur); // trapezoid over 1-s steps, as the simulator does
        prev = cur;
        m.push(cur);
        assert_eq!(sm.markov_rad_s()[1], 0.0);
    }
    // Attitude: single axis, so C_i^p = Rx(∫ m dt).
    let err = (sm.c_ip() - rx(angle)).norm();
    assert!(
        err < 1e-12 + 1e-9 * angle.abs(),
        "attitude off ∫m dt by {err:e}"
    );
    // Statistics: T/τ = 500 correlation times. Relative 1σ of the sample std ≈ sqrt(τ/2T)... ≈ 3 %,
    // of the lag-τ autocorrelation ≈ 0.045; tolerances ≈ 4σ.
    let mean = m.iter().sum::<f64>() / m.len() as f64;
    let var = m.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / m.len() as f64;
    let sd = var.sqrt() / DEG_H;
    assert!((sd / sigma - 1.0).abs() < 0.12, "std {sd} deg/h vs {sigma}");
    let lag = (tau_h * 3600.0) as usize;
    let cov = m
        .iter()
        .zip(&m[lag..])
        .map(|(a, b)| (a - mean) * (b - mean))
        .sum::<f64>()
        / (m.len() - lag) as f64;
    let rho = cov / var;
    assert!(
        (rho - (-1.0f64).exp()).abs() < 0.15,
        "autocorrelation at τ: {rho}"
    );
}

#[test]
fn accelerometer_effects_change_samples_by_their_formula() {
    let base_s = quiet(Scenario::paper().coefficients, vec![], 3.0, 10.0);
    let base = simulate(&base_s);
    let b = [1e-4, -2e-4, 3e-5];
    let sc = [100.0, -50.0, 20.0];
    let mis = [1e-4, -2e-4, 3e-4, -4e-4, 5e-4, -6e-4]; // xy xz yx yz zx zy
    let cases: Vec<(InjectedEffect, Box<dyn Fn(&[f64; 3]) -> [f64; 3]>)> = vec![
        (
            InjectedEffect::AccBias { b_mps2: b },
            Box::new(move |_: &[f64; 3]| b),
        ),
        (
            InjectedEffect::AccScale { s_ppm: sc },
            Box::new(move |a: &[f64; 3]| {
                [
                    sc[0] * 1e-6 * a[0],
                    sc[1] * 1e-6 * a[1],
                    sc[2] * 1e-6 * a[2],
                ]
            }),
        ),
        (
            InjectedEffect::AccMisalign { m_rad: mis },
            Box::new(move |a: &[f64; 3]| {
                [
                    mis[0] * a[1] + mis[1] * a[2],
                    mis[2] * a[0] + mis[3] * a[2],
                    mis[4] * a[0] + mis[5] * a[1],
                ]
            }),
        ),
    ];
    for (effect, delta) in cases {
        let mut s = base_s.clone();
        s.effects = vec![effect.clone()];
        let sim = simulate(&s);
        assert_eq!(sim.samples.len(), base.samples.len());
        for (x, y) in sim.samples.iter().zip(&base.samples) {
            let d = delta(&y.specific_force_mps2);
            for i in 0..3 {
                let got = x.specific_force_mps2[i] - y.specific_force_mps2[i];
                assert!(
                    (got - d[i]).abs() < 1e-14 * 10.0,
                    "{}: axis {i} t {}: {got:e} vs {:e}",
                    effect.name(),
                    x.t_s,
                    d[i]
                );
            }
        }
    }
    // With noise, the accelerometer noise stream does not depend on the effects: a bias still
    // shifts every sample by exactly b.
    let mut noisy = Scenario::paper();
    noisy.hours = 0.5;
    let a = simulate(&noisy);
    noisy.effects = vec![InjectedEffect::AccBias { b_mps2: b }];
    let c = simulate(&noisy);
    for (x, y) in c.samples.iter().zip(&a.samples) {
        for i in 0..3 {
            assert!(
                (x.specific_force_mps2[i] - y.specific_force_mps2[i] - b[i]).abs() < 1e-14 * 10.0
            );
        }
    }
}

#[test]
fn drift_effects_change_the_attitude_and_accelerometer_effects_do_not() {
    let base = quiet(Scenario::paper().coefficients, vec![], 2.0, 60.0);
    let a0 = simulate(&base).truth.final_c_0p;
    for (e, moves) in [
        ("acc-bias=1e-3,1e-3,1e-3", false),
        ("acc-scale=1000,1000,1000", false),
        ("acc-misalign=1e-3,1e-3,1e-3,1e-3,1e-3,1e-3", false),
        ("drift-trend=0.01,0,0", true),
        ("g2=0,0,0,0,0,0.001,0,0,0,0,0,0,0,0,0,0,0,0", true),
        ("temp-drift=0,0.1,0", true),
        ("drift-markov=0,0,0.01:1,1,1", true),
    ] {
        let mut s = base.clone();
        s.effects = vec![e.parse().unwrap()];
        let a = simulate(&s).truth.final_c_0p;
        let diff: f64 = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| (a[i][j] - a0[i][j]).abs())
            .sum();
        assert_eq!(diff > 1e-9, moves, "{e}: attitude change {diff:e}");
    }
}

#[test]
fn same_seed_same_samples_other_seed_other_samples() {
    let mut s = Scenario::paper();
    s.hours = 2.0;
    s.effects = vec![
        "drift-markov=0.01,0.01,0.01:5,5,5".parse().unwrap(),
        "temp-drift=0.01,0,0".parse().unwrap(),
    ];
    let a = simulate(&s);
    let b = simulate(&s);
    assert_eq!(a.samples, b.samples);
    assert_eq!(a.truth, b.truth);
    s.seed = 2;
    let c = simulate(&s);
    assert_ne!(a.samples[1..], c.samples[1..]);
}

/// Raw noise std from third differences: Δ³ of white noise has variance 20σ² (1+9+9+1), while
/// the signal's third difference is ~gΩ³·rate³ (4e-12 m/s² at 1 s), negligible.
/// Spread of the estimate: Δ³ is MA(3) with autocorrelations −15/20, 6/20, −1/20, so the
/// variance estimate over N points has relative std sqrt(2·Σρ²/N) = sqrt(4.62/N) and the std
/// estimate half of that: 1.3 % at N = 7200 (2 h at 1 s). Tolerance 6 % ≈ 5σ.
fn third_difference_sigma(x: &[f64]) -> f64 {
    let d: Vec<f64> = x
        .windows(4)
        .map(|w| w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0])
        .collect();
    (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64 / 20.0).sqrt()
}

#[test]
fn raw_noise_matches_the_configured_sigma() {
    for (rate, hours) in [(1.0, 2.0), (0.5, 1.0), (10.0, 20.0)] {
        let mut s = Scenario::paper();
        s.rate_s = rate;
        s.hours = hours;
        let sim = simulate(&s);
        let want = s.accel_sigma_mps2 * (60.0f64 / rate).sqrt();
        for axis in 0..3 {
            let x: Vec<f64> = sim
                .samples
                .iter()
                .map(|p| p.specific_force_mps2[axis])
                .collect();
            let got = third_difference_sigma(&x);
            assert!(
                (got / want - 1.0).abs() < 0.06,
                "rate {rate} axis {axis}: {got:e} vs {want:e}"
            );
        }
    }
    // 1e-5 g per 60-s mean → 7.6e-4 m/s² per 1-s sample (model.md).
    let s = Scenario::paper();
    assert!((s.accel_sigma_mps2 * 60f64.sqrt() - 7.59e-4).abs() < 1e-6);
}

#[test]
fn gyro_random_walk_has_the_configured_density() {
    // Zero drift: C_i^p = exp(−[φ×]) with φ a random walk, Var φ_i = q·T, q = 1e-8 deg²/h in rad²/s.
    // 300 seeds × 3 axes = 900 draws: relative 1σ of the variance ≈ sqrt(2/900) = 4.7 %; tol 20 %.
    let mut s = Scenario::paper();
    s.coefficients = [0.0; 12];
    let q = 1e-8 * (PI / 180.0).powi(2) / 3600.0;
    let t = 1800.0;
    let mut sum2 = 0.0;
    let mut n = 0.0;
    for seed in 0..300 {
        s.seed = seed;
        let mut sm = Simulator::new(&s);
        sm.advance_to(t, 1.0);
        let c = sm.c_ip();
        for v in [c[(1, 2)], c[(2, 0)], c[(0, 1)]] {
            sum2 += v * v;
            n += 1.0;
        }
    }
    let ratio = sum2 / n / (q * t);
    assert!((ratio - 1.0).abs() < 0.2, "angle variance / (qT) = {ratio}");
}

#[test]
fn paper_run_is_fast_and_truth_round_trips() {
    let s = Scenario::paper();
    let t0 = std::time::Instant::now();
    let sim = simulate(&s);
    let dt = t0.elapsed();
    eprintln!("60 h at 1 s: {} samples in {dt:?}", sim.samples.len());
    assert_eq!(sim.samples.len(), 216_001);
    assert_eq!(sim.samples.last().unwrap().t_s, 216_000.0);
    assert!(dt.as_secs_f64() < 5.0, "{dt:?}");
    // The platform turned by tens of degrees relative to inertial space over 60 h; θ is
    // unwrapped and consistent with the final DCM.
    let th = sim.truth.final_theta_rad;
    let c = Matrix3::from_fn(|i, j| sim.truth.final_c_0p[i][j]);
    let e = euler(&c);
    for i in 0..3 {
        assert!(wrap(th[i] - e[i]).abs() < 1e-12);
    }
    // Write a short run and read it back.
    let mut short = s.clone();
    short.hours = 0.1;
    short.effects = vec!["acc-bias=1e-4,0,0".parse().unwrap()];
    let sim = simulate(&short);
    let dir = std::env::temp_dir().join(format!("driftid-simulator-truth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("run.csv");
    let tp = write_simulation(&csv, &sim, false).unwrap();
    assert_eq!(tp, dir.join("run.truth.json"));
    let truth = read_truth(&tp).unwrap();
    assert_eq!(truth, sim.truth);
    assert_eq!(truth.coefficient_array(), s.coefficients);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&tp).unwrap()).unwrap();
    assert_eq!(json["coefficients"]["DYy"], 0.1);
    assert_eq!(json["effects"][0]["name"], "acc-bias");
    let rec = host_tool::recording::read_recording(&csv).unwrap();
    assert_eq!(rec.samples, sim.samples);
    assert_eq!(rec.meta.latitude_deg, Some(39.1));
    assert_eq!(rec.meta.gravity_mps2, Some(s.gravity()));
    std::fs::remove_dir_all(&dir).ok();
}

/// model.md's θ̇ equations integrated with RK4 (10-s steps) over the paper's 60 h must land on
/// the simulator's DCM attitude: two independent kinematic formulations of the same truth.
#[test]
fn euler_angle_integration_agrees_with_the_dcm_truth_over_60_hours() {
    let mut s = Scenario::paper().without_noise();
    s.rate_s = 3600.0;
    let truth = simulate(&s).truth;
    let c = s.coefficients;
    let g = s.gravity();
    let (sl, cl) = lat().sin_cos();
    let we0 = Vector3::new(0.0, OMEGA * cl, OMEGA * sl);
    let f = |th: &Vector3<f64>| {
        let (sx, cx) = th.x.sin_cos();
        let (sy, cy) = th.y.sin_cos();
        let (sz, cz) = th.z.sin_cos();
        let rxm = Matrix3::new(1.0, 0.0, 0.0, 0.0, cx, sx, 0.0, -sx, cx);
        let rym = Matrix3::new(cy, 0.0, -sy, 0.0, 1.0, 0.0, sy, 0.0, cy);
        let rzm = Matrix3::new(cz, sz, 0.0, -sz, cz, 0.0, 0.0, 0.0, 1.0);
        let cm = rzm * rym * rxm;
        let a = cm * Vector3::new(0.0, 0.0, g);
        let w = paper_drift(&c, &a) - cm * we0;
        let txd = (cz * w.x - sz * w.y) / cy;
        Vector3::new(txd, sz * w.x + cz * w.y, w.z - sy * txd)
    };
    let h = 10.0;
    let mut th = Vector3::zeros();
    for _ in 0..(60 * 360) {
        let k1 = f(&th);
        let k2 = f(&(th + k1 * (h / 2.0)));
        let k3 = f(&(th + k2 * (h / 2.0)));
        let k4 = f(&(th + k3 * h));
        th += (k1 + 2.0 * k2 + 2.0 * k3 + k4) * (h / 6.0);
    }
    let ft = truth.final_theta_rad;
    let err = (th - Vector3::from(ft)).norm();
    eprintln!("θ(60 h): RK4 {th:?}, DCM truth {ft:?}, difference {err:e} rad");
    assert!(err < 1e-8, "θ differs by {err:e} rad");
}
