//! Profiling aid: 100 000 EKF steps of the paper's 15-state model on a simulated run (RK4, 60 s),
//! for `valgrind --tool=callgrind` or `perf`. Prints the time per step.
//!
//! Run: `cargo run --release -p host-tool --example step_profile [euler]`.
use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::{Averager, Ekf, Model, Propagation, Sample, Site, PAPER_EFFECTS};

fn main() {
    let euler = std::env::args().nth(1).as_deref() == Some("euler");
    let site = Site::new(39.1, None);
    let mut sc = host_tool::simulate::Scenario::paper();
    sc.rate_s = 60.0;
    let sim = host_tool::simulate::simulate(&sc);
    let mut avg = Averager::new(60.0, [1e-5 * site.gravity_mps2; 3]);
    let meas: Vec<_> = sim
        .samples
        .iter()
        .filter_map(|s| {
            avg.push(&Sample {
                t_s: s.t_s,
                specific_force: s.specific_force_mps2,
                temp_c: f64::NAN,
            })
        })
        .collect();
    let prop = if euler {
        Propagation::Euler
    } else {
        Propagation::default()
    };
    let model = Model::new(site, &PAPER_EFFECTS, arw_deg2ph_to_rad2ps(1e-8), prop).unwrap();
    let steps: usize = std::env::var("STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000);
    let t = std::time::Instant::now();
    let mut done = 0;
    let mut last = 0.0;
    while done < steps {
        let mut ekf = Ekf::<15>::with_default_prior(model).unwrap();
        for m in &meas {
            last = ekf.step(m).unwrap().nis;
            done += 1;
            if done == steps {
                break;
            }
        }
    }
    let dt = t.elapsed().as_secs_f64();
    println!(
        "{done} steps ({}) in {dt:.3} s: {:.3} µs/step (last NIS {last:.3})",
        if euler { "Euler" } else { "RK4" },
        dt / done as f64 * 1e6
    );
}
