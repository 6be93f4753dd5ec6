//! Speed of the core: one EKF step of the paper's 15-state model (structured predict + Joseph
//! update, RK4 over 60 s), and one 60-h identification (2 passes + smoother) from a CSV file.
//!
//! Run: `cargo bench -p host-tool --bench ekf`.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::{Averager, Ekf, Measurement, Model, Propagation, Site, PAPER_EFFECTS};
use host_tool::identify::{identify, prepare, Config};

/// 120 h of measurements of the paper's platform (simulated once), so a benchmark never runs
/// out of input.
fn measurements(site: Site) -> Vec<Measurement> {
    let mut sc = host_tool::simulate::Scenario::paper();
    sc.hours = 120.0;
    sc.rate_s = 60.0;
    let sim = host_tool::simulate::simulate(&sc);
    let mut avg = Averager::new(60.0, [1e-5 * site.gravity_mps2; 3]);
    let mut out: Vec<Measurement> = sim
        .samples
        .iter()
        .filter_map(|s| {
            avg.push(&estimator_core::Sample {
                t_s: s.t_s,
                specific_force: s.specific_force_mps2,
                temp_c: f64::NAN,
            })
        })
        .collect();
    out.extend(avg.flush());
    out
}

fn ekf_step(c: &mut Criterion) {
    let site = Site::new(39.1, None);
    let meas = measurements(site);
    for (name, prop) in [
        ("ekf_step_rk4_60s", Propagation::default()),
        ("ekf_step_euler_60s", Propagation::Euler),
    ] {
        let model = Model::new(site, &PAPER_EFFECTS, arw_deg2ph_to_rad2ps(1e-8), prop).unwrap();
        // Warm the filter up for 30 h so the step runs on a realistic state and covariance.
        let mut warm = Ekf::<15>::with_default_prior(model).unwrap();
        for m in &meas[..1800] {
            warm.step(m).unwrap();
        }
        c.bench_function(name, |b| {
            b.iter_batched_ref(
                || (warm.clone(), 1800usize),
                |(ekf, k)| {
                    let r = ekf.step(&meas[*k]).unwrap();
                    *k += 1;
                    r
                },
                BatchSize::SmallInput,
            )
        });
    }
}

fn identify_60h_csv(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("driftid-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("paper60h.csv");
    let mut sc = host_tool::simulate::Scenario::paper();
    sc.rate_s = 1.0;
    let sim = host_tool::simulate::simulate(&sc);
    host_tool::recording::write_recording(&path, &sim.meta, &sim.samples).unwrap();
    let mut group = c.benchmark_group("identify");
    group.sample_size(10);
    group.bench_function("identify_60h_1s_csv", |b| {
        b.iter(|| {
            let loaded = host_tool::cli::common::load(&path, None).unwrap();
            let cfg = Config::default();
            let model = Model::new(
                loaded.site,
                &PAPER_EFFECTS,
                arw_deg2ph_to_rad2ps(1e-8),
                Propagation::default(),
            )
            .unwrap();
            let prep = prepare(loaded.site, &loaded.samples, &cfg).unwrap();
            identify(&model, &prep, &cfg).unwrap()
        })
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, ekf_step, identify_60h_csv);
criterion_main!(benches);
