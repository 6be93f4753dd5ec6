//! Timing aid: where `driftid identify` spends its time inside the process, phase by phase
//! (read, prepare, identify, Cramér–Rao bound, consistency), the minimum of N runs with the
//! memory warm. The process itself (`driftid identify FILE`) adds start-up and first touches.
//!
//! Run: `cargo run --release -p host-tool --example phases -- RUN.csv [N]` (N = 20).
use std::time::Instant;

use host_tool::identify::{build_model, identify, prepare_oriented, try_cramer_rao_bound, Config};

/// The allocator `driftid` runs with.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[global_allocator]
static ALLOC: host_tool::heap::HugePages = host_tool::heap::HugePages;

fn main() -> anyhow::Result<()> {
    host_tool::cli::common::keep_freed_memory();
    let mut args = std::env::args().skip(1);
    let Some(path) = args.next().map(std::path::PathBuf::from) else {
        anyhow::bail!("usage: phases RUN.csv [N]");
    };
    let runs: usize = args.next().map_or(Ok(20), |s| s.parse())?;
    let mut best = [f64::INFINITY; 6];
    for _ in 0..runs.max(1) {
        let t0 = Instant::now();
        let loaded =
            host_tool::cli::common::load(host_tool::catalog::Catalog::builtin(), &path, None)?;
        let t1 = Instant::now();
        let cfg = Config::default();
        let prep = prepare_oriented(
            loaded.site,
            &loaded.samples,
            &cfg,
            loaded.initial_orientation_rad,
        )?;
        drop(loaded); // as `driftid identify` does
        let t2 = Instant::now();
        let catalog = host_tool::catalog::Catalog::builtin();
        let effects = catalog.model_effects(&[])?;
        let model = build_model(prep.site, &effects, &cfg)?;
        let id = identify(&model, &prep, &cfg)?;
        let t3 = Instant::now();
        let bound = try_cramer_rao_bound(&model, &prep, &id.best().value)?;
        let t4 = Instant::now();
        let check = host_tool::cli::identify::consistency_of(&id, &prep);
        let t5 = Instant::now();
        std::hint::black_box((&bound, &check));
        let took = [t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4, t5 - t0];
        for (b, d) in best.iter_mut().zip(took) {
            *b = b.min(d.as_secs_f64() * 1e3);
        }
    }
    println!(
        "min of {runs} (ms): read {:.2}, prepare {:.2}, identify {:.2}, bound {:.2}, consistency {:.2}; total {:.2}",
        best[0], best[1], best[2], best[3], best[4], best[5]
    );
    Ok(())
}
