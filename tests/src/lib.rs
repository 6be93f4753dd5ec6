//! Shared helpers for the host tests.

pub mod firmware {
    //! What the QEMU tests share: building the QEMU firmware, and the host core's single pass
    //! the firmware's estimates are compared with.

    use std::path::{Path, PathBuf};
    use std::process::Command;
    use std::sync::OnceLock;
    use std::time::Instant;

    use estimator_core::Sample;
    use protocol::{Config, Counters, Estimate, RawSample};

    /// The workspace root.
    pub fn workspace() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .parent()
            .unwrap()
            .to_path_buf()
    }

    /// Builds the QEMU firmware once per test binary (own target dir: the outer `cargo test`
    /// holds the lock on the workspace's) and returns the ELF. Panics — the test fails, never
    /// skips — when qemu-system-arm or the thumbv7em-none-eabihf target is missing.
    pub fn qemu_elf() -> &'static Path {
        static ELF: OnceLock<PathBuf> = OnceLock::new();
        ELF.get_or_init(|| {
            match Command::new("qemu-system-arm").arg("--version").output() {
                Ok(o) if o.status.success() => {}
                _ => panic!("qemu-system-arm is missing: run .ci/setup (apt-get install qemu-system-arm)"),
            }
            let root = workspace();
            let target_dir = root.join("target/qemu-fw");
            let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
            let t = Instant::now();
            let out = Command::new(cargo)
                .current_dir(&root)
                .args(["build", "-p", "firmware", "--profile", "firmware"])
                .args(["--target", "thumbv7em-none-eabihf"])
                .args(["--features", "board-qemu", "--target-dir"])
                .arg(&target_dir)
                // The firmware's flags come from .cargo/config.toml; host flags must not leak in.
                .env_remove("RUSTFLAGS")
                .env_remove("CARGO_ENCODED_RUSTFLAGS")
                .env_remove("CARGO_BUILD_TARGET")
                .output()
                .expect("running cargo");
            assert!(
                out.status.success(),
                "building the QEMU firmware failed (is the thumbv7em-none-eabihf target installed? .ci/setup adds it):\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
            eprintln!("firmware built in {:.1} s", t.elapsed().as_secs_f64());
            target_dir.join("thumbv7em-none-eabihf/firmware/firmware")
        })
    }

    /// The host core's single pass on `samples` (the same screening, averaging and EKF as the
    /// firmware), as the estimate messages the firmware sends.
    pub fn host_single_pass(config: &Config, samples: &[RawSample]) -> Vec<Estimate> {
        host_single_pass_counted(config, samples).0
    }

    /// [`host_single_pass`] with the sample and filter counters the firmware reports for the
    /// same samples (accepted, and rejected by the screening per reason).
    pub fn host_single_pass_counted(
        config: &Config,
        samples: &[RawSample],
    ) -> (Vec<Estimate>, Counters) {
        let mut out = Vec::new();
        let samples = samples.iter().map(|s| Sample {
            t_s: s.t_s,
            specific_force: s.specific_force,
            temp_c: s.temp_c,
        });
        let counters = firmware_app::app::single_pass(config, samples, |e| out.push(e)).unwrap();
        (out, counters)
    }
}
