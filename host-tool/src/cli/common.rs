//! Pieces every analysis subcommand shares: loading a recording and building the model.

use crate::steps::Progress;
use std::path::Path;

use anyhow::Context as _;
use estimator_core::{Propagation, Sample, Site};

use crate::catalog::Catalog;
use crate::identify::{Config, Prepared};
use crate::recording::{read_recording, RawSample};

/// Options of the model and the filter, common to identify/diagnose/report.
#[derive(clap::Args, Clone, Debug)]
pub struct ModelArgs {
    /// Latitude, deg (overrides the recording's `latitude_deg`).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::latitude_deg)]
    pub latitude_deg: Option<f64>,
    /// Filter period, s (raw samples are averaged over it).
    #[arg(long, default_value_t = 60.0, allow_hyphen_values = true, value_parser = super::args::period_s)]
    pub period_s: f64,
    /// Gyro angle-random-walk variance density, deg²/h.
    #[arg(long, default_value_t = 1e-8, allow_hyphen_values = true, value_parser = super::args::arw)]
    pub arw: f64,
    /// Raw-sample accelerometer noise 1σ, m/s² (one value or x,y,z); default: estimated from the data.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_parser = super::args::raw_sigma)]
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
    /// Start attitude prior 1σ, arcsec: TILT (each level axis) and AZIMUTH. The start is
    /// estimated with it; default 5,30 (docs/model.md, "Set-up parameters").
    #[arg(long, value_delimiter = ',', num_args = 2, value_names = ["TILT", "AZIMUTH"], value_parser = super::args::nonneg_f64)]
    pub alignment_arcsec: Option<Vec<f64>>,
    /// Latitude 1σ, deg; default: half the last written digit of the latitude (/√3), at least 1e-4.
    #[arg(long, value_parser = super::args::nonneg_f64)]
    pub latitude_sigma_deg: Option<f64>,
    /// Recorder clock rate 1σ, ppm (default 20: a quartz crystal; 1 for a disciplined clock).
    #[arg(long, value_parser = super::args::nonneg_f64)]
    pub clock_sigma_ppm: Option<f64>,
    /// Gravity 1σ, ppm of g (default 30: normal gravity or a map value, altitude and anomaly).
    #[arg(long, value_parser = super::args::nonneg_f64)]
    pub gravity_sigma_ppm: Option<f64>,
    /// Daily tilt of the apparent vertical, 1σ per component, arcsec (default 1).
    #[arg(long, value_parser = super::args::nonneg_f64)]
    pub vertical_tilt_arcsec: Option<f64>,
    /// Drift that follows the solar day (a laboratory's thermal cycle), 1σ per component, deg/h
    /// (default 3e-4; 0 when the gyros' temperature is held or the drift is modelled from it).
    #[arg(long, value_parser = super::args::nonneg_f64)]
    pub daily_drift_deg_h: Option<f64>,
    /// Drift that changes steadily over the run (slow temperature changes, run-in), 1σ of each
    /// axis' change over a day, deg/h (default 3e-4; 0 when known to be absent).
    #[arg(long, value_parser = super::args::nonneg_f64)]
    pub drift_trend_deg_h_per_day: Option<f64>,
    /// Drift proportional to the recorded temperature (where it varies), 1σ per axis, deg/h per
    /// °C (default 0.002; 0 when the gyros' temperature sensitivity is known to be negligible).
    #[arg(long, value_parser = super::args::nonneg_f64)]
    pub temp_drift_deg_h_per_c: Option<f64>,
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

impl ModelArgs {
    /// The identification settings these options give.
    pub(crate) fn config(&self) -> anyhow::Result<Config> {
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
        let mut setup = crate::identify::setup::SetupPriors::default();
        if let Some(v) = self.alignment_arcsec.as_deref() {
            if let [tilt, azimuth] = v {
                setup.tilt_arcsec = *tilt;
                setup.azimuth_arcsec = *azimuth;
            } else {
                anyhow::bail!(
                    "--alignment-arcsec takes TILT,AZIMUTH, got {} values",
                    v.len()
                );
            }
        }
        setup.assumed = [
            self.latitude_sigma_deg.is_none(),
            self.clock_sigma_ppm.is_none(),
            self.gravity_sigma_ppm.is_none(),
        ];
        setup.latitude_sigma_deg = self.latitude_sigma_deg.or(setup.latitude_sigma_deg);
        setup.clock_sigma_ppm = self.clock_sigma_ppm.unwrap_or(setup.clock_sigma_ppm);
        setup.gravity_sigma_ppm = self.gravity_sigma_ppm.unwrap_or(setup.gravity_sigma_ppm);
        setup.vertical_tilt_arcsec = self
            .vertical_tilt_arcsec
            .unwrap_or(setup.vertical_tilt_arcsec);
        setup.daily_drift_deg_h = self.daily_drift_deg_h.unwrap_or(setup.daily_drift_deg_h);
        setup.drift_trend_deg_h_per_day = self
            .drift_trend_deg_h_per_day
            .unwrap_or(setup.drift_trend_deg_h_per_day);
        setup.temp_drift_deg_h_per_c = self
            .temp_drift_deg_h_per_c
            .unwrap_or(setup.temp_drift_deg_h_per_c);
        Ok(Config {
            setup,
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
    /// A 64-bit hash of the samples' bits (times and specific forces): equal for the same data
    /// (a copy, another formatting of it), so that a run given twice is refused
    /// ([`super::joint::refuse_same_data`]); two different recordings collide with probability
    /// 2⁻⁶⁴.
    pub fingerprint: u64,
    /// 1-based file line of each sample: a refusal that blames one sample names it.
    pub lines: Vec<u32>,
}

impl Loaded {
    /// The file line of the sample stamped `t_s` (on the samples' time axis), if there is one.
    pub(crate) fn line_at(&self, t_s: f64) -> Option<u32> {
        let k = self.samples.iter().position(|s| s.t_s == t_s)?;
        self.lines.get(k).copied()
    }
}

/// The recording at `path`, loaded, prepared at its stated orientation
/// ([`crate::identify::prepare_oriented`]); an error names the file, and a refusal that blames
/// one sample (irregular time stamps) its line, `FILE:LINE: …`, as the reader's errors do.
pub(crate) fn prepare_loaded(
    path: &Path,
    loaded: &Loaded,
    cfg: &Config,
) -> anyhow::Result<Prepared> {
    crate::identify::prepare_oriented(
        loaded.site,
        &loaded.samples,
        cfg,
        loaded.initial_orientation_rad,
    )
    .map_err(|e| {
        let line = e
            .downcast_ref::<crate::quality::Refusal>()
            .and_then(|r| r.at_s)
            .and_then(|t| loaded.line_at(t));
        match line {
            Some(line) => e.context(format!("{}:{line}", path.display())),
            None => e.context(format!("{}", path.display())),
        }
    })
}

/// The longest span a recording may have, s (about 3.2 years; a drift identification run lasts
/// hours to weeks). A longer one — typically one stray stamp far in the future — would make the
/// filter propagate across it step by step for hours.
pub(crate) const MAX_SPAN_S: f64 = 1e8;

/// The longest gap between two samples, s (11.6 days). Measured: a 2-h run with its last
/// sample 1e6 s later is identified; 1e7 s later the attitude's uncertainty grown across the gap
/// (the drift integrated over months) makes the filter fail with a covariance error.
pub(crate) const MAX_GAP_S: f64 = 1e6;

/// The coarsest float resolution a time stamp may have, as a fraction of the interval since the
/// previous sample. Beyond it the stamps' offset has eaten their fraction: at 1e15 s a double
/// resolves only 0.125 s, so 1-s stamps come out 0.875, 1 or 1.125 s apart.
pub(crate) const MAX_STAMP_RESOLUTION: f64 = 1e-3;

/// Absolute time stamps (Unix time, a clock's uptime, a negative start): times are taken
/// relative to the first sample, said once on stderr (a recording starting at t_s = 0 is left
/// as it is). Refused, naming the line: a stamp whose float resolution at its magnitude is
/// coarser than [`MAX_STAMP_RESOLUTION`] of the interval since the previous sample, a gap
/// longer than [`MAX_GAP_S`], a span longer than [`MAX_SPAN_S`].
fn relative_times(
    path: &Path,
    samples: &mut [RawSample],
    lines: &[u32],
    warn: bool,
) -> anyhow::Result<()> {
    let Some(first) = samples.first() else {
        return Ok(());
    };
    let t0 = first.t_s;
    let line = |k: usize| lines.get(k).copied().unwrap_or(0);
    // The distance from |t| to the next double: the stamp's resolution.
    let resolution = |t: f64| {
        let a = t.abs();
        f64::from_bits(a.to_bits() + 1) - a
    };
    for k in 1..samples.len() {
        let (prev, t) = (samples[k - 1].t_s, samples[k].t_s);
        let res = resolution(t).max(resolution(prev));
        if res > MAX_STAMP_RESOLUTION * (t - prev) {
            anyhow::bail!(
                "{}:{}: t_s = {t:?} is {:.3e} s after the previous sample, but at this magnitude a time stamp resolves only {res:.3e} s (a double's precision): the offset of the time stamps leaves them unusable; write the time relative to the start of the run",
                path.display(),
                line(k),
                t - prev
            );
        }
    }
    if t0 != 0.0 {
        // Once per file and process: the joint diagnose reads a run more than once.
        static SAID: std::sync::Mutex<Vec<std::path::PathBuf>> = std::sync::Mutex::new(Vec::new());
        let mut said = SAID.lock().unwrap_or_else(|e| e.into_inner());
        if warn && !said.iter().any(|p| p == path) {
            said.push(path.to_path_buf());
            eprintln!(
                "driftid: warning: {}:{}: the time stamps start at t_s = {t0:?}: time is taken relative to the first sample (it is t = 0; an initial orientation in the metadata is the platform's at that sample)",
                path.display(),
                line(0)
            );
        }
        let mut prev = f64::NEG_INFINITY;
        for (k, s) in samples.iter_mut().enumerate() {
            s.t_s -= t0;
            // Stamps closer than the resolution at the span's magnitude would merge.
            anyhow::ensure!(
                s.t_s > prev,
                "{}:{}: t_s = {:?} is not after the previous sample once taken relative to the first ({t0:?}); the stamps are too close for their offset",
                path.display(),
                line(k),
                s.t_s + t0
            );
            prev = s.t_s;
        }
    }
    Ok(())
}

/// Refuses, naming the line, a gap longer than [`MAX_GAP_S`] or a span longer than
/// [`MAX_SPAN_S`] — in seconds: a time column in another unit that the data-quality checks
/// recognise (ms, µs, minutes, hours: [`crate::quality::time`]) is measured in it, as they will
/// convert it.
fn check_gaps(path: &Path, site: &Site, samples: &[Sample], lines: &[u32]) -> anyhow::Result<()> {
    use crate::quality::time::{time_scale, RATE_TOLERANCE, UNITS};
    let (Some(first), Some(last)) = (samples.first(), samples.last()) else {
        return Ok(());
    };
    let tolerance = 1.0 / RATE_TOLERANCE..=RATE_TOLERANCE;
    // Seconds per unit of the time column.
    let unit = time_scale(site, samples)
        .filter(|s| !tolerance.contains(s))
        .and_then(|s| UNITS.iter().find(|(f, _)| tolerance.contains(&(s / f))))
        .map_or(1.0, |(f, _)| *f);
    if (last.t_s - first.t_s) * unit <= MAX_GAP_S {
        return Ok(());
    }
    let line = |k: usize| lines.get(k).copied().unwrap_or(0);
    for k in 1..samples.len() {
        let (prev, t) = (samples[k - 1].t_s, samples[k].t_s);
        if (t - prev) * unit > MAX_GAP_S {
            anyhow::bail!(
                "{}:{}: this sample comes {:.3e} s after the previous one (line {}): a gap may last at most {MAX_GAP_S:e} s (11.6 days; across a longer one the platform's attitude is not predictable); a stray time stamp? split the recording there",
                path.display(),
                line(k),
                (t - prev) * unit,
                line(k - 1)
            );
        }
        if (t - first.t_s) * unit > MAX_SPAN_S {
            anyhow::bail!(
                "{}:{}: this sample comes {:.3e} s after the first (line {}): a recording may span at most {MAX_SPAN_S:e} s (about 3 years)",
                path.display(),
                line(k),
                (t - first.t_s) * unit,
                line(0)
            );
        }
    }
    Ok(())
}

/// [`Loaded::fingerprint`] of `samples`.
fn fingerprint(samples: &[Sample]) -> u64 {
    use std::hash::{Hash as _, Hasher as _};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for s in samples {
        s.t_s.to_bits().hash(&mut h);
        for v in s.specific_force {
            v.to_bits().hash(&mut h);
        }
    }
    h.finish()
}

/// Reads a recording (and the columns `catalog`'s file effects use); a bad file is an error
/// naming file and line.
pub fn load(
    catalog: &Catalog,
    path: &Path,
    latitude_override: Option<f64>,
) -> anyhow::Result<Loaded> {
    load_with(catalog, path, latitude_override, true)
}

/// [`load`] without its warnings on stderr (a repaired last line, relative time stamps): for a
/// first look at a recording that is loaded again, with its warnings, later (the joint
/// `diagnose`'s check for the same data twice).
pub(crate) fn load_quietly(
    catalog: &Catalog,
    path: &Path,
    latitude_override: Option<f64>,
) -> anyhow::Result<Loaded> {
    load_with(catalog, path, latitude_override, false)
}

fn load_with(
    catalog: &Catalog,
    path: &Path,
    latitude_override: Option<f64>,
    warn: bool,
) -> anyhow::Result<Loaded> {
    let spin = crate::progress::spinner(&format!("reading {}", path.display()));
    let rec = read_recording(path);
    spin.finish_and_clear();
    let mut rec = rec?;
    for r in rec.repairs.iter().filter(|_| warn) {
        eprintln!("driftid: warning: {r}");
    }
    relative_times(path, &mut rec.samples, &rec.lines, warn)?;
    // File effects that use extra columns of the recording (`columns = [...]`) read them now.
    catalog.bind_columns(path, &rec.samples, &rec.lines)?;
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
    let samples: Vec<Sample> = rec.samples.into_iter().map(|s| Sample::from(&s)).collect();
    check_gaps(path, &site, &samples, &rec.lines)?;
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
        fingerprint: fingerprint(&samples),
        samples,
        description: rec.meta.description.clone(),
        initial_orientation_rad,
        lines: rec.lines,
    })
}

/// The model with the paper's drift and the chosen effects (lives in [`crate::identify`]).
pub use crate::identify::build_model;

/// Asks whether the metadata latitude is why a model does not fit ([`crate::diagnose::latitude`]),
/// against the catalog effects' evidence gains on the same scale (`rivals` of the measurements,
/// called only when the profile finds a latitude worth weighing against them): the profile's
/// finding, if any, for `prep.findings`, where it is a fault (the result is not trusted, and no
/// physical effect is added to explain it). Call it once the fit `fitted` of `effects` on `prep`
/// is inconsistent.
pub(crate) fn name_a_wrong_latitude(
    prep: &Prepared,
    (effects, fitted): (
        &[&dyn estimator_core::effects::Effect],
        &crate::identify::Identification,
    ),
    cfg: &Config,
    rivals: impl FnOnce(&Prepared) -> Vec<(String, f64)>,
    progress: &Progress,
) -> Option<crate::quality::Finding> {
    progress.note(|| "the model does not fit: profiling the latitude".into());
    crate::diagnose::latitude::check_with(prep, effects, cfg, Some(fitted), || rivals(prep))
}

/// The catalog effects' evidence gains for the model `effects` fitted as `id` on `prep`: the
/// rivals of a wrong latitude. The leaders by the linearised evidence
/// ([`crate::diagnose::alternatives`]) are refitted, as the latitude is: far from the fit the
/// one-step evidence overstates what a refit gains.
pub(crate) fn rivals(
    prep: &Prepared,
    catalog: &Catalog,
    effects: &[&dyn estimator_core::effects::Effect],
    cfg: &Config,
    id: &crate::identify::Identification,
    progress: &Progress,
) -> Vec<(String, f64)> {
    let dcfg = crate::diagnose::DiagnoseConfig {
        identify: cfg.clone(),
        progress: progress.within("the model does not fit"),
        ..Default::default()
    };
    progress.note(|| "the model does not fit: weighing the catalog effects".into());
    let Ok(alts) = crate::diagnose::alternatives::weigh(prep, catalog, effects, &dcfg, id) else {
        return vec![];
    };
    let leaders: Vec<String> = alts
        .iter()
        .take(crate::diagnose::select::REFIT_LEADERS)
        .map(|a| a.effect.clone())
        .collect();
    crate::diagnose::select::refit(prep, catalog, (effects, id), &leaders, &dcfg)
        .into_iter()
        .map(|r| (r.effect, r.evidence_gain))
        .collect()
}

/// The rivals of a wrong latitude on a fit `id` of `effects` on `prep` that does not fit: the
/// catalog's effects refitted ([`rivals`]) and the set-up misstated or moved within its priors,
/// weighed on the same fit ([`crate::diagnose::misstated::weigh`]): a wrong latitude is one
/// misstatement among them. Without them a clock 1000 ppm fast was named a latitude 0.07° off
/// (the profile then free to fit the data's gravity at every latitude), and its run refused by
/// a joint fit.
pub(crate) fn latitude_rivals(
    prep: &Prepared,
    catalog: &Catalog,
    effects: &[&dyn estimator_core::effects::Effect],
    cfg: &Config,
    id: &crate::identify::Identification,
    progress: &Progress,
) -> Vec<(String, f64)> {
    use crate::diagnose::misstated;
    let (catalog_rivals, set_up) = rayon::join(
        || rivals(prep, catalog, effects, cfg, id, progress),
        || {
            let unc = crate::identify::setup::uncertainty(effects, prep, cfg, id).ok()?;
            let (mis, within) = misstated::weigh(effects, prep, cfg, (id, &unc), None)
                .ok()?
                .on_the_stated_fit();
            let named = not_the_latitude(&mis).map(|a| (a.effect.clone(), a.evidence_gain));
            Some(named.chain(within).collect::<Vec<_>>())
        },
    );
    [catalog_rivals, set_up.unwrap_or_default()].concat()
}

/// The misstatements but the latitude's: the rivals of the latitude's profile, which weighs that
/// one itself (a latitude 0.5° off was "not told from `latitude misstated`", itself).
fn not_the_latitude<'a>(
    mis: impl IntoIterator<Item = &'a crate::diagnose::alternatives::Alternative>,
) -> impl Iterator<Item = &'a crate::diagnose::alternatives::Alternative> {
    mis.into_iter()
        .filter(|a| a.misstated.as_ref().is_none_or(|m| m.index != 0))
}

/// The starting model fitted on `prep` when its data are trusted (else `None`). A misfit is
/// first weighed against a misstated set-up ([`crate::diagnose::misstated`]; one that beats every
/// explanation is repaired in `prep` and `cfg` and the model refitted there), then against the
/// latitude ([`name_a_wrong_latitude`]). `diagnose` and `report` start their ladder from this
/// fit ([`crate::diagnose::ladder_from`]). `known` takes the starting fit's set-up uncertainty,
/// for the final assessment to reuse if the ladder adds nothing.
pub(crate) fn starting_fit(
    prep: &mut Prepared,
    catalog: &Catalog,
    effects: &[&dyn estimator_core::effects::Effect],
    cfg: &mut Config,
    (stated, at_start): (&mut Option<Prepared>, &mut crate::assess::AtTheStart),
    known: &mut Option<crate::identify::setup::Computed>,
    progress: &Progress,
) -> anyhow::Result<Option<crate::identify::Identification>> {
    use crate::diagnose::misstated;
    use crate::identify::setup;
    if !prep.untrusted_reasons().is_empty() {
        return Ok(None);
    }
    progress.note(|| "fitting the starting model".into());
    let id = crate::diagnose::latitude::fit_or_name_the_latitude(prep, effects, cfg)?;
    let consistent = super::identify::consistency_of(&id, prep).is_none_or(|c| c.is_consistent());
    progress.note(|| "the starting model: the set-up's uncertainty".into());
    let unc = setup::uncertainty(effects, prep, cfg, &id)?;
    let mut computed = setup::Computed::new(effects, prep, cfg, &id, unc.clone());
    progress.note(|| "the starting model: weighing a misstated set-up".into());
    // Where the ladder adds nothing, the final assessment settles and weighs them about this
    // fit again: kept for it.
    let weighed = misstated::weigh(effects, prep, cfg, (&id, &unc), Some(&mut computed))?;
    *known = Some(computed);
    // A fit within its noise may still rest on a set-up the data move within its priors (a
    // clock 300 ppm fast reads as a latitude within its digits): the ladder would then add an
    // effect that absorbs the move (a daily drift, 8σ off, trusted) where the set-up is one more
    // explanation to weigh first, as for a misfit.
    if consistent && weighed.stated_gain.is_none_or(|g| g <= 0.0) {
        return Ok(Some(id));
    }
    let moved_within = weighed.within_priors;
    let about: Vec<(&'static str, f64)> = id
        .params
        .iter()
        .map(|p| p.name)
        .zip(weighed.about.iter().copied())
        .collect();
    // On the scale of the rivals, refitted at the stated set-up: the misstatements' gains over
    // that fit, and the stated set-up within its priors as one more rival.
    let (mis, within_priors) = weighed.on_the_stated_fit();
    // The catalog's rivals (refits, most of this check) are weighed now only where the set-up
    // could win without them: more rivals never make a repair, a confounded set-up or the
    // set-up within its priors win (`to_repair`, `confounded`: the best against the rest).
    // Otherwise only the latitude's profile may need them.
    let set_up_may_win = misstated::to_repair(&mis, &[]).is_some()
        || misstated::confounded(&mis, &[]).is_some()
        || within_priors.as_ref().is_some_and(|(_, g)| *g > 0.0);
    let catalog_rivals = |p: &Prepared| rivals(p, catalog, effects, cfg, &id, progress);
    let mut rivals = match set_up_may_win {
        true => catalog_rivals(prep),
        false => vec![],
    };
    // Contradicted or moved within its priors, a repair must beat the catalog's effects with
    // the set-up within its priors (crate::assess's rule).
    if let Some(w) = moved_within {
        if misstated::to_repair(&mis, &rivals).is_some() {
            // The same rivals as `identify`'s (crate::assess::rivals_within_priors).
            let dcfg = crate::diagnose::DiagnoseConfig {
                identify: cfg.clone(),
                progress: progress.clone(),
                ..Default::default()
            };
            progress
                .note(|| "weighing the catalog effects with the set-up within its priors".into());
            let stated_fit = (prep.clone(), id.clone());
            rivals.extend(crate::assess::rivals_within_priors(
                catalog,
                effects,
                &stated_fit,
                &dcfg,
                w,
            )?);
        }
    }
    let catalog_best = rivals.iter().map(|r| r.1).fold(0.0, f64::max);
    rivals.extend(within_priors.clone());
    if let Some(m) = misstated::to_repair(&mis, &rivals) {
        let (p, c) = misstated::repair(prep, cfg, &m, &mis, &rivals);
        let model = build_model(p.site, effects, &c)?;
        let refitted = crate::assess::refit_repaired(&model, &p, &c, &id).map_err(|e| {
            let why = crate::assess::unfitted_repair(prep, &p, &e);
            anyhow::anyhow!("{why}: correct the metadata and run again")
        })?;
        *prep = p;
        *cfg = c;
        return Ok(Some(refitted));
    }
    if let Some(f) = misstated::confounded(&mis, &rivals) {
        prep.findings.push(f);
        return Ok(Some(id));
    }
    if within_priors.is_some_and(|(_, g)| g > catalog_best) {
        // The set-up within its priors explains the misfit better than any effect: the ladder
        // starts where prior and data put it.
        // `stated` keeps the set-up as stated for the final assessment, whose own settling
        // applies the priors once.
        let settled = setup::settle(effects, prep.clone(), cfg, id, None)?;
        *stated = Some(std::mem::replace(prep, settled.prep));
        return Ok(Some(settled.id));
    }
    rivals.extend(not_the_latitude(&mis).map(|a| (a.effect.clone(), a.evidence_gain)));
    // The ladder climbs from the set-up as stated: each misstatement is a rival of what it adds.
    *at_start = crate::assess::AtTheStart {
        misstated: mis,
        about,
    };
    let all_rivals = |p: &Prepared| match set_up_may_win {
        true => rivals,
        false => [catalog_rivals(p), rivals].concat(),
    };
    let found = name_a_wrong_latitude(prep, (effects, &id), cfg, all_rivals, progress);
    prep.findings.extend(found);
    Ok(Some(id))
}

/// The final fit `id` of `effects` where it is to be assessed: on `stated` when the ladder ran on
/// a settled set-up ([`starting_fit`]), refitted there; else on `prep` as it is.
pub(crate) fn for_assessment(
    stated: Option<Prepared>,
    prep: &Prepared,
    effects: &[&dyn estimator_core::effects::Effect],
    cfg: &Config,
    id: crate::identify::Identification,
) -> anyhow::Result<(Prepared, crate::identify::Identification)> {
    match stated {
        Some(p) => {
            let model = build_model(p.site, effects, cfg)?;
            let refitted = crate::identify::identify_from(&model, &p, cfg, &id)?;
            Ok((p, refitted))
        }
        None => Ok((prep.clone(), id)),
    }
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
pub(crate) fn trusted_or(reasons: Vec<String>) -> anyhow::Result<()> {
    if reasons.is_empty() {
        Ok(())
    } else {
        Err(Untrusted(reasons).into())
    }
}

/// Prints the data-quality findings (first, before any number).
pub(crate) fn print_findings(findings: &[crate::quality::Finding]) {
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
///
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters (glibc serialises it with allocation); it is
    // called at the start of main and of a bench, before the allocations it concerns.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 256 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 512 << 20);
    }
    // The heap's next 64 MB advised for huge pages once, as a large block is
    // ([`crate::heap::HugePages`]), and handed back: freed, it joins the top of the heap, which
    // is not trimmed, so the blocks this thread allocates later (below the large-block size:
    // the time axis, the filter's states and innovations, the screening's copies) are carved from
    // advised memory and fault in 2 MiB at a time. On the 60-h run: ~2 300 page faults -> ~1 300,
    // ~2.5 ms less CPU time; the peak resident memory +2 MB (only touched pages count).
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    drop(std::hint::black_box(Vec::<u8>::with_capacity(
        PREADVISED_HEAP_BYTES,
    )));
}

/// The allocator's set-up under a memory budget the user gave (`--max-memory-mib`): freed memory
/// goes back to the system and the threads share one arena. Kept memory ([`keep_freed_memory`])
/// stays in the arena of the thread that freed it, and glibc gives threads arenas of their own:
/// after the set-up's passes on rayon's workers each arena held its own peak, and a 3-h run at
/// `--period-s 1` refused at a 48-MiB budget was resident 78–102 MB, past the bound's promise
/// (the budget plus ~30 MB). Under a budget the resident peak follows the heap's; the passes
/// fault their buffers in anew (about a tenth more time).
pub fn return_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: as in keep_freed_memory; malloc_trim only returns free memory to the system.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 1);
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 << 10);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 128 << 10);
        libc::malloc_trim(0);
    }
}

/// Heap advised for huge pages at start-up ([`keep_freed_memory`]).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const PREADVISED_HEAP_BYTES: usize = 64 << 20;

/// What `identify`, `diagnose`, `report` and `plan` call first: the catalog of this run, the
/// built-in effects plus those of the `--effects` files.
pub(crate) fn catalog(args: &ModelArgs) -> anyhow::Result<Catalog> {
    Catalog::load(&args.effects)
}

/// How a command that used `catalog` ends: a file effect that evaluated to NaN or infinity
/// spoiled the numbers, whatever the command concluded, so its message (naming the file, line,
/// effect and expression) replaces the `result` (exit 2).
pub(crate) fn unless_numeric_failure(
    catalog: &Catalog,
    result: anyhow::Result<()>,
) -> anyhow::Result<()> {
    match catalog.numeric_failure() {
        Some(failure) => Err(anyhow::anyhow!("{failure}")),
        None => result,
    }
}
