//! Speed of the host: one EKF step of the paper's 15-state model as the host runs it
//! (`MAX_STATES` capacity), reading a 60-h recording at 1 s (11.7 MB), one 60-h identification
//! from that CSV (converged: 2 passes + smoother; and single pass), and `diagnose` on it (the
//! ladder, as `driftid diagnose` runs it). The firmware-sized step is benched in estimator-core
//! (`cargo bench -p estimator-core --bench step`).
//!
//! The `commands` group runs `driftid identify` and `driftid diagnose` as a user does (a
//! process, the whole command: reading, screening, the fit, the set-up's uncertainty, the
//! alternatives) on 60-h recordings at 1 s that the model fits and that it does not: clean, a
//! hidden catalog effect (an accelerometer bias), two (g² drift and an accelerometer bias), an
//! uncatalogued drift (a 30-h sine), a bias
//! step (a fault), a metadata latitude 0.5° off (repaired). Issue 31's table; its CPU time is
//! the child's (`RUSAGE_CHILDREN`).
//!
//! Run: `cargo bench -p host-tool --bench ekf` (one group: `… --bench ekf -- read`).
//!
//! The times are the process's CPU time (`CLOCK_PROCESS_CPUTIME_ID`), not wall time: the
//! machines this runs on are shared, and wall time there measures the neighbours' load. For
//! single-threaded work it is the time the work takes on an idle core. Reading a recording uses
//! every core ([`host_tool::recording::read_recording`]: blocks on threads), so its CPU time is
//! the sum over them; the `_wall` benches give the elapsed time of the read and of the whole
//! identification (meaningful on an otherwise idle machine).

use std::path::{Path, PathBuf};
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};

/// `driftid`'s allocator (huge pages for large blocks, `host_tool::heap`): the benches measure
/// what the program does.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[global_allocator]
static ALLOC: host_tool::heap::HugePages = host_tool::heap::HugePages;
use estimator_core::model::MAX_STATES;
use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::{Averager, Ekf, Measurement, Model, Propagation, Site, PAPER_EFFECTS};
use host_tool::diagnose::{ladder, DiagnoseConfig};
use host_tool::identify::{identify, prepare, prepare_oriented, Config};

/// CPU time of this process so far.
fn cpu_time() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec through the valid pointer.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime");
    Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

/// Runs `f` `iters` times and returns the CPU time it took (criterion's `iter_custom`).
fn cpu<O>(iters: u64, mut f: impl FnMut() -> O) -> Duration {
    let start = cpu_time();
    for _ in 0..iters {
        std::hint::black_box(f());
    }
    cpu_time() - start
}

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
        ("ekf_step_rk4_60s_host", Propagation::default()),
        ("ekf_step_euler_60s_host", Propagation::Euler),
    ] {
        let model = Model::new(site, &PAPER_EFFECTS, arw_deg2ph_to_rad2ps(1e-8), prop).unwrap();
        // Warm the filter up for 30 h so the step runs on a realistic state and covariance; the
        // timed loop steps on through the remaining 90 h and starts again from the warm state.
        let mut warm = Ekf::<MAX_STATES>::with_default_prior(model).unwrap();
        for m in &meas[..1800] {
            warm.step(m).unwrap();
        }
        let mut ekf = warm.clone();
        let mut k = 1800;
        c.bench_function(name, |b| {
            b.iter_custom(|iters| {
                cpu(iters, || {
                    if k == meas.len() {
                        ekf = warm.clone();
                        k = 1800;
                    }
                    let r = ekf.step(&meas[k]).unwrap();
                    k += 1;
                    r.nis
                })
            })
        });
    }
}

/// The paper's 60-h run at 1 s written as a recording (once per bench process).
fn recording_60h() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("driftid-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("paper60h.csv");
    if !path.exists() {
        let mut sc = host_tool::simulate::Scenario::paper();
        sc.rate_s = 1.0;
        let sim = host_tool::simulate::simulate(&sc);
        host_tool::recording::write_recording(&path, &sim.meta, &sim.samples).unwrap();
    }
    path
}

fn read(c: &mut Criterion) {
    let path = recording_60h();
    let bytes = std::fs::metadata(&path).unwrap().len();
    let mut group = c.benchmark_group("read");
    group.sample_size(20);
    group.throughput(Throughput::Bytes(bytes));
    group.bench_function("read_recording_60h_1s", |b| {
        b.iter_custom(|iters| {
            cpu(iters, || {
                host_tool::recording::read_recording(&path)
                    .unwrap()
                    .samples
                    .len()
            })
        })
    });
    group.bench_function("read_recording_60h_1s_wall", |b| {
        b.iter(|| {
            host_tool::recording::read_recording(&path)
                .unwrap()
                .samples
                .len()
        })
    });
    group.finish();
}

fn identify_from_csv(path: &Path, smoother_iterations: usize) -> usize {
    let loaded =
        host_tool::cli::common::load(host_tool::catalog::Catalog::builtin(), path, None).unwrap();
    let cfg = Config {
        smoother_iterations,
        ..Config::default()
    };
    let model = Model::new(
        loaded.site,
        &PAPER_EFFECTS,
        arw_deg2ph_to_rad2ps(cfg.arw_deg2_per_h),
        cfg.propagation,
    )
    .unwrap();
    let prep = prepare(loaded.site, &loaded.samples, &cfg).unwrap();
    identify(&model, &prep, &cfg).unwrap().trajectory.len()
}

fn identify_60h_csv(c: &mut Criterion) {
    // The allocator as `driftid` sets it up (what the process does, measured in-process).
    host_tool::cli::common::keep_freed_memory();
    let path = recording_60h();
    let mut group = c.benchmark_group("identify");
    group.sample_size(10);
    group.bench_function("identify_60h_1s_csv", |b| {
        b.iter_custom(|iters| {
            cpu(iters, || {
                identify_from_csv(&path, Config::default().smoother_iterations)
            })
        })
    });
    group.bench_function("identify_60h_1s_csv_single_pass", |b| {
        b.iter_custom(|iters| cpu(iters, || identify_from_csv(&path, 0)))
    });
    group.bench_function("identify_60h_1s_csv_wall", |b| {
        b.iter(|| identify_from_csv(&path, Config::default().smoother_iterations))
    });
    group.finish();
}

/// `diagnose`'s ladder on the recording at `path`, from the CSV: the number of rungs.
fn diagnose_from_csv(path: &Path) -> usize {
    let loaded =
        host_tool::cli::common::load(host_tool::catalog::Catalog::builtin(), path, None).unwrap();
    let cfg = DiagnoseConfig::default();
    let prep = prepare_oriented(
        loaded.site,
        &loaded.samples,
        &cfg.identify,
        loaded.initial_orientation_rad,
    )
    .unwrap();
    let catalog = host_tool::catalog::Catalog::builtin();
    let effects = catalog.model_effects(&[]).unwrap();
    ladder(&prep, catalog, &effects, &cfg).unwrap().rungs.len()
}

fn diagnose_60h_csv(c: &mut Criterion) {
    let path = recording_60h();
    let mut group = c.benchmark_group("diagnose");
    group.sample_size(10);
    group.bench_function("diagnose_ladder_60h_1s_csv", |b| {
        b.iter_custom(|iters| cpu(iters, || diagnose_from_csv(&path)))
    });
    group.bench_function("diagnose_ladder_60h_1s_csv_wall", |b| {
        b.iter(|| diagnose_from_csv(&path))
    });
    group.finish();
}

/// A 60-h run at 1 s written by `driftid simulate` with `args` (once per bench process).
fn simulated_60h(name: &str, args: &[&str]) -> PathBuf {
    let path = recording_60h().with_file_name(format!("{name}.csv"));
    if !path.exists() {
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_driftid"))
            .args(["simulate", "--hours", "60", "--rate-s", "1"])
            .args(args)
            .arg("--out")
            .arg(&path)
            .output()
            .unwrap();
        assert!(status.status.success(), "{status:?}");
    }
    path
}

/// CPU time of this process's finished children so far.
#[cfg(unix)]
fn children_cpu_time() -> Duration {
    // SAFETY: getrusage writes the struct it is given.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut ru) };
    let tv = |t: libc::timeval| Duration::new(t.tv_sec as u64, t.tv_usec as u32 * 1000);
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

/// `driftid COMMAND path` as a process; its exit status (0 trusted, 3 not).
fn driftid(command: &str, path: &Path) -> i32 {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_driftid"))
        .arg(command)
        .arg(path)
        .output()
        .unwrap();
    let code = out.status.code().unwrap_or(-1);
    assert!(
        matches!(code, 0 | 3),
        "{command} {}: {out:?}",
        path.display()
    );
    code
}

fn commands(c: &mut Criterion) {
    let cases = [
        ("clean", recording_60h()),
        (
            "acc_bias",
            simulated_60h("acc_bias", &["--effect", "acc-bias=1e-4,-1e-4,1e-4"]),
        ),
        (
            "g2_and_acc_bias",
            simulated_60h(
                "g2_acc_bias",
                &[
                    "--effect",
                    "g2=5e-5,0,0,0,0,0,0,5e-5,0,0,0,0,0,0,5e-5,0,0,0",
                    "--effect",
                    "acc-bias=1e-4,-1e-4,1e-4",
                ],
            ),
        ),
        (
            "uncatalogued_sine",
            simulated_60h("sine30h", &["--effect", "drift-sine=7e-4,-5e-4,6e-4:30"]),
        ),
        (
            "bias_step",
            simulated_60h("bias_step", &["--fault", "step=y,4e-4,30"]),
        ),
        (
            "latitude_half_degree_off",
            simulated_60h("lat05", &["--latitude-error-deg", "0.5"]),
        ),
        (
            "gauss_markov_wander",
            simulated_60h(
                "wander",
                &[
                    "--seed",
                    "7",
                    "--effect",
                    "drift-markov=8e-4,8e-4,8e-4:5,5,5",
                ],
            ),
        ),
    ];
    let mut group = c.benchmark_group("commands");
    group.sample_size(10);
    for command in ["identify", "diagnose"] {
        for (name, path) in &cases {
            group.bench_function(format!("{command}_{name}_60h_1s_wall"), |b| {
                b.iter(|| driftid(command, path))
            });
            #[cfg(unix)]
            group.bench_function(format!("{command}_{name}_60h_1s_cpu"), |b| {
                b.iter_custom(|iters| {
                    let start = children_cpu_time();
                    for _ in 0..iters {
                        driftid(command, path);
                    }
                    children_cpu_time() - start
                })
            });
        }
    }
    group.finish();
}

criterion_group!(
    benches,
    ekf_step,
    read,
    identify_60h_csv,
    diagnose_60h_csv,
    commands
);
criterion_main!(benches);
