//! Speed of one EKF step (predict over 60 s + Joseph update) of the paper's model (3 angles +
//! 12 drift coefficients) and of an extended model (+ drift-markov, acc-scale), in the filter
//! as the firmware sizes it (`CAP` = the model's dimension) and as the host does (`MAX_STATES`).
//!
//! Run: `cargo bench -p estimator-core --bench step`. The measurements are the model's own
//! prediction along a truth trajectory (the paper's coefficients) with a deterministic ±1e-5 g
//! dither: the filter runs on a realistic state and covariance after a 30-h warm-up.
//!
//! The times are the process's CPU time (`CLOCK_PROCESS_CPUTIME_ID`), not wall time: the
//! machines this runs on are shared, and wall time there measures the neighbours' load.

use criterion::{criterion_group, criterion_main, Criterion};
use estimator_core::effects::{AccScale, DriftMarkov};
use estimator_core::model::MAX_STATES;
use estimator_core::propagate::{propagate, Transition};
use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::{Effect, Ekf, Measurement, Model, PaperDrift, Propagation, Site};
use nalgebra::Vector3;

/// CPU time of this process so far.
fn cpu_time() -> std::time::Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec through the valid pointer.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime");
    std::time::Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

const PERIOD_S: f64 = 60.0;
const UPDATES: usize = 7200; // 120 h
const WARM: usize = 1800; // 30 h

/// Truth: the paper's coefficients (deg/h, deg/h/(m/s²)), zero for any further state.
fn measurements(model: &Model<'_>) -> Vec<Measurement> {
    let n = model.dim();
    let mut x = vec![0.0; n];
    let truth = [
        0.1, 0.01, -0.02, 0.03, -0.05, 0.02, 0.01, -0.01, 0.08, -0.03, 0.02, 0.015,
    ];
    x[3..15].copy_from_slice(&truth);
    let var = (1e-5 * model.site().gravity_mps2).powi(2);
    let mut tr = Transition::<MAX_STATES>::default();
    let mut h = [Vector3::zeros(); MAX_STATES];
    let mut state = 0x9e3779b97f4a7c15u64;
    let mut dither = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2e-4
    };
    (1..=UPDATES)
        .map(|k| {
            let t0 = (k - 1) as f64 * PERIOD_S;
            propagate(model, &mut x, t0, PERIOD_S, 0.0, 0.0, &mut tr);
            let t = k as f64 * PERIOD_S;
            let a = model.measurement(&x, t, 0.0, 0.0, &mut h);
            Measurement {
                t_s: t,
                specific_force: [a.x + dither(), a.y + dither(), a.z + dither()],
                temp_c: f64::NAN,
                count: 60,
                variance: [var; 3],
                time_var_s2: 0.0,
            }
        })
        .collect()
}

fn bench_model<const CAP: usize>(c: &mut Criterion, name: &str, model: Model<'_>) {
    let meas = measurements(&model);
    let mut warm = Ekf::<CAP>::with_default_prior(model).unwrap();
    for m in &meas[..WARM] {
        warm.step(m).unwrap();
    }
    let mut ekf = warm.clone();
    let mut k = WARM;
    c.bench_function(name, |b| {
        b.iter_custom(|iters| {
            let start = cpu_time();
            for _ in 0..iters {
                if k == UPDATES {
                    ekf = warm.clone();
                    k = WARM;
                }
                let r = ekf.step(&meas[k]).unwrap();
                k += 1;
                std::hint::black_box(r.nis);
            }
            cpu_time() - start
        })
    });
}

static EXTENDED: [&dyn Effect; 3] = [
    &PaperDrift,
    &DriftMarkov {
        sigma_degph: 0.01,
        tau_h: 5.0,
    },
    &AccScale,
];

fn steps(c: &mut Criterion) {
    let site = Site::new(39.1, None);
    let arw = arw_deg2ph_to_rad2ps(1e-8);
    for (label, prop) in [
        ("rk4", Propagation::default()),
        ("euler", Propagation::Euler),
    ] {
        let paper = Model::new(site, &estimator_core::PAPER_EFFECTS, arw, prop).unwrap();
        bench_model::<15>(c, &format!("step_paper_{label}_cap15"), paper);
    }
    let paper = Model::new(
        site,
        &estimator_core::PAPER_EFFECTS,
        arw,
        Propagation::default(),
    );
    bench_model::<MAX_STATES>(c, "step_paper_rk4_cap64", paper.unwrap());
    let ext = Model::new(site, &EXTENDED, arw, Propagation::default()).unwrap();
    bench_model::<21>(c, "step_extended21_rk4_cap21", ext);
}

criterion_group!(benches, steps);
criterion_main!(benches);
