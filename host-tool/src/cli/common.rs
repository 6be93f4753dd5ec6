//! Pieces every analysis subcommand shares: loading a recording and building the model.

use std::path::Path;

use anyhow::Context as _;
use estimator_core::{Propagation, Sample, Site};

use crate::identify::{Config, Prepared};
use crate::recording::read_recording;

/// Options of the model and the filter, common to identify/diagnose/report.
#[derive(clap::Args, Clone, Debug)]
pub struct ModelArgs {
    /// Latitude, deg (overrides the recording's `latitude_deg`).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::latitude_deg)]
    pub latitude_deg: Option<f64>,
    /// Filter period, s (raw samples are averaged over it).
    #[arg(long, default_value_t = 60.0, allow_hyphen_values = true, value_parser = super::args::positive_f64)]
    pub period_s: f64,
    /// Gyro angle-random-walk variance density, deg²/h.
    #[arg(long, default_value_t = 1e-8, allow_hyphen_values = true, value_parser = super::args::nonneg_f64)]
    pub arw: f64,
    /// Raw-sample accelerometer noise 1σ, m/s² (one value or x,y,z); default: estimated from the data.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_parser = super::args::positive_f64)]
    pub raw_sigma: Option<Vec<f64>>,
    /// Use the paper's Euler step (X + f·dt) instead of RK4 (to reproduce the paper; inaccurate).
    #[arg(long)]
    pub euler: bool,
    /// Stop after the paper's single EKF pass (no re-linearisation, no smoother).
    #[arg(long)]
    pub single_pass: bool,
    /// Effects added to the paper's model, comma-separated (e.g. `acc-bias,drift-markov`).
    #[arg(long = "with", value_delimiter = ',')]
    pub with: Vec<String>,
    /// TOML file of effects defined by the user, added to the catalog for this run (repeatable);
    /// see the README, "Effects defined in a file".
    #[arg(long = "effects", value_name = "FILE")]
    pub effects: Vec<std::path::PathBuf>,
    /// Leave out the samples of a window, hours of the recording's time column (e.g. a
    /// disturbance you know of: `--exclude 12.5..12.6`); repeatable, reported as an `excluded`
    /// finding. With several runs it applies to each.
    #[arg(long = "exclude", value_name = "T0..T1", allow_hyphen_values = true, value_parser = super::args::hours_window)]
    pub exclude: Vec<(f64, f64)>,
}

/// Loads and registers the `--effects` files: call first in identify, diagnose and report.
pub use crate::effects_file::load_effects_args;

impl ModelArgs {
    /// The identification settings these options give.
    pub fn config(&self) -> anyhow::Result<Config> {
        let raw_sigma_mps2 = match self.raw_sigma.as_deref() {
            None => None,
            Some([s]) => Some([*s; 3]),
            Some([x, y, z]) => Some([*x, *y, *z]),
            Some(v) => anyhow::bail!("--raw-sigma takes 1 or 3 values, got {}", v.len()),
        };
        if !(self.period_s > 0.0 && self.period_s.is_finite()) {
            anyhow::bail!(
                "--period-s must be a positive number of seconds, got {}",
                self.period_s
            );
        }
        Ok(Config {
            period_s: self.period_s,
            arw_deg2_per_h: self.arw,
            propagation: if self.euler {
                Propagation::Euler
            } else {
                Propagation::default()
            },
            raw_sigma_mps2,
            smoother_iterations: if self.single_pass { 0 } else { 3 },
            exclude_s: self
                .exclude
                .iter()
                .map(|&(a, b)| (a * 3600.0, b * 3600.0))
                .collect(),
            ..Config::default()
        })
    }
}

/// A recording loaded for analysis.
pub struct Loaded {
    /// Site (latitude from the file or the command line; gravity from the file or normal gravity).
    pub site: Site,
    /// Samples in the core's form.
    pub samples: Vec<Sample>,
    /// Free-text description from the file, if any.
    pub description: Option<String>,
    /// The platform's orientation at t = 0 from the metadata `initial_orientation_deg`, rad
    /// (zero: level, the default).
    pub initial_orientation_rad: [f64; 3],
}

/// Reads a recording; a bad file is an error naming file and line.
pub fn load(path: &Path, latitude_override: Option<f64>) -> anyhow::Result<Loaded> {
    let spin = crate::progress::spinner(&format!("reading {}", path.display()));
    let rec = read_recording(path);
    spin.finish_and_clear();
    let rec = rec?;
    for r in &rec.repairs {
        eprintln!("driftid: warning: {r}");
    }
    let latitude_deg = latitude_override
        .or(rec.meta.latitude_deg)
        .with_context(|| {
            format!(
                "{}: no `# latitude_deg:` line in the file; give --latitude-deg",
                path.display()
            )
        })?;
    if !(-90.0..=90.0).contains(&latitude_deg) {
        anyhow::bail!(
            "{}: latitude {latitude_deg} deg is not in [-90, 90]",
            path.display()
        );
    }
    let site = Site::new(latitude_deg, rec.meta.gravity_mps2);
    // In place: a `Sample` is no larger than a `RawSample`, so the conversion reuses the
    // recording's buffer instead of faulting in a second one (~9 MB for a 60-h run at 1 s).
    let samples = rec.samples.into_iter().map(|s| Sample::from(&s)).collect();
    let initial_orientation_rad = match rec
        .meta
        .extra
        .iter()
        .find(|(k, _)| k == crate::simulate::INITIAL_ORIENTATION_KEY)
    {
        None => [0.0; 3],
        Some((_, v)) => {
            let parts: Vec<Option<f64>> = v
                .split(',')
                .map(|p| p.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
                .collect();
            match parts.as_slice() {
                [Some(a), Some(b), Some(c)] => [a.to_radians(), b.to_radians(), c.to_radians()],
                _ => anyhow::bail!(
                    "{}: metadata initial_orientation_deg: {v:?} is not three finite angles tx, ty, tz in degrees",
                    path.display()
                ),
            }
        }
    };
    Ok(Loaded {
        site,
        samples,
        description: rec.meta.description.clone(),
        initial_orientation_rad,
    })
}

/// The model with the paper's drift and the chosen effects (lives in [`crate::identify`]).
pub use crate::identify::build_model;

/// Asks whether the metadata latitude is why a model does not fit ([`crate::quality::latitude`]):
/// the profile's finding, if any, joins `prep.findings`, where it is a fault (the result is not
/// trusted, and no physical effect is added to explain it). Call it once a fit is inconsistent.
pub fn name_a_wrong_latitude(
    prep: &mut Prepared,
    effects: &[&'static dyn estimator_core::effects::Effect],
    cfg: &Config,
) {
    let spin = crate::progress::spinner("the model does not fit: profiling the latitude");
    let found = crate::quality::latitude::check(prep, effects, cfg);
    spin.finish_and_clear();
    prep.findings.extend(found);
}

/// The starting model fitted on `prep` when its data are trusted (else `None`), a misfit first
/// checked against the latitude ([`name_a_wrong_latitude`]). `diagnose` and `report` start their
/// ladder from this fit ([`crate::diagnose::ladder_from`]).
pub fn starting_fit(
    prep: &mut Prepared,
    effects: &[&'static dyn estimator_core::effects::Effect],
    cfg: &Config,
) -> anyhow::Result<Option<crate::identify::Identification>> {
    if !prep.untrusted_reasons().is_empty() {
        return Ok(None);
    }
    let model = build_model(prep.site, effects, cfg)?;
    let id = crate::identify::identify(&model, prep, cfg)?;
    if super::identify::consistency_of(&id, prep).is_some_and(|c| !c.is_consistent()) {
        name_a_wrong_latitude(prep, effects, cfg);
    }
    Ok(Some(id))
}

/// The numbers were computed but the tool does not trust them (exit status 3); the reasons say
/// why. The numbers have been printed already, flagged.
#[derive(Debug)]
pub struct Untrusted(pub Vec<String>);

impl std::fmt::Display for Untrusted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the result is not trusted: {}", self.0.join("; "))
    }
}

impl std::error::Error for Untrusted {}

/// Ends a command: `Ok` when there is no reason for distrust, else [`Untrusted`].
pub fn trusted_or(reasons: Vec<String>) -> anyhow::Result<()> {
    if reasons.is_empty() {
        Ok(())
    } else {
        Err(Untrusted(reasons).into())
    }
}

/// Prints the data-quality findings (first, before any number).
pub fn print_findings(findings: &[crate::quality::Finding]) {
    if findings.is_empty() {
        println!("data quality: no finding");
        return;
    }
    println!("data quality: {} finding(s)", findings.len());
    for f in findings {
        println!("  {}", f.line());
    }
}

/// The allocator's set-up for `driftid` (and the benches that measure it): glibc serves a block
/// above its mmap threshold (128 kB, raised at most to the size of the largest block freed so
/// far) with a fresh mapping and unmaps it on free. `identify` allocates
/// the same ~10 MB of smoother buffers for each Gauss–Newton pass, so every pass faulted them in
/// anew: about 10 % of the process's time was in the kernel for it (perf, 60-h recording).
/// Blocks up to 256 MB now come from the heap, and freed memory is kept for the next pass
/// instead of being trimmed; the peak is unchanged (the same blocks, reused).
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters (glibc serialises it with allocation); it is
    // called at the start of main and of a bench, before the allocations it concerns.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 256 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 512 << 20);
    }
    // The heap's next 64 MB advised for huge pages once, as a large block is
    // ([`crate::alloc::HugePages`]), and handed back: freed, it joins the top of the heap, which
    // is not trimmed, so the blocks this thread allocates later (below the large-block size:
    // the time axis, the filter's states and innovations, the screening's copies) are carved from
    // advised memory and fault in 2 MiB at a time. On the 60-h run: ~2 300 page faults -> ~1 300,
    // ~2.5 ms less CPU time; the peak resident memory +2 MB (only touched pages count).
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    drop(std::hint::black_box(Vec::<u8>::with_capacity(
        PREADVISED_HEAP_BYTES,
    )));
}

/// Heap advised for huge pages at start-up ([`keep_freed_memory`]).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const PREADVISED_HEAP_BYTES: usize = 64 << 20;
