use host_tool::identify::*;
use std::time::Instant;
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[global_allocator]
static A: host_tool::alloc::HugePages = host_tool::alloc::HugePages;
fn main() {
    host_tool::cli::common::keep_freed_memory();
    let path = std::path::PathBuf::from(std::env::args().nth(1).unwrap());
    let n: usize = std::env::args().nth(2).map_or(20, |s| s.parse().unwrap());
    let mut best = [f64::INFINITY; 8];
    for _ in 0..n {
        let t0 = Instant::now();
        let loaded = host_tool::cli::common::load(&path, None).unwrap();
        let t1 = Instant::now();
        let cfg = Config::default();
        let prep = prepare_oriented(
            loaded.site,
            &loaded.samples,
            &cfg,
            loaded.initial_orientation_rad,
        )
        .unwrap();
        let t2 = Instant::now();
        let effects = host_tool::catalog::model_effects(&[]).unwrap();
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let t3 = Instant::now();
        let b = try_cramer_rao_bound(&model, &prep, &id.best().value).unwrap();
        let t4 = Instant::now();
        let c = host_tool::cli::identify::consistency_of(&id, &prep);
        let t5 = Instant::now();
        std::hint::black_box((&b, &c));
        let d = [t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4, t5 - t0];
        for (k, x) in d.iter().enumerate() {
            best[k] = best[k].min(x.as_secs_f64() * 1e3);
        }
    }
    println!(
        "read {:.2} prepare {:.2} identify {:.2} crb {:.2} consist {:.2} total {:.2} ms",
        best[0], best[1], best[2], best[3], best[4], best[5]
    );
}
