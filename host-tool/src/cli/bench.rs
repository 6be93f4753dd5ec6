//! `driftid bench accuracy`: Monte Carlo over seeds (rayon) of the identification's accuracy
//! against the Cramér–Rao bound and its consistency (NEES), at several run lengths.

use estimator_core::{Measurement, Sample};
use indicatif::ParallelProgressIterator;
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::common::build_model;
use crate::catalog::{self, Catalog};
use crate::identify::{identify, prepare, try_cramer_rao_bound, Config, Prepared};
use crate::simulate::{simulate, Scenario};
use crate::stats::chi2_quantile;

/// Arguments of `driftid bench`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// What to benchmark: `accuracy` (estimates against the Cramér–Rao bound) or `calibration`
    /// (false-alarm rate of the diagnosis on clean runs) or `sensitivity` (detection rate of
    /// each effect at 1× and 2× the size the diagnosis says it detects with 90 % power) or
    /// `screening` (false alarms of the data-quality screening on clean runs, one row per
    /// `--hours`: runs with any finding, with an untrusting one).
    /// Speed benchmarks are `cargo bench`.
    #[arg(value_parser = ["accuracy", "calibration", "sensitivity", "screening"])]
    pub what: String,
    /// Number of seeds.
    #[arg(long, default_value_t = 24, allow_hyphen_values = true, value_parser = super::args::seed_count)]
    pub seeds: u64,
    /// Run lengths at which to evaluate, h.
    #[arg(long, value_delimiter = ',', default_value = "12,24,30,48,60", allow_hyphen_values = true, value_parser = super::args::hours)]
    pub hours: Vec<f64>,
    /// Raw sample interval, s.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true, value_parser = super::args::rate_s)]
    pub rate_s: f64,
    /// Latitude of the simulated runs, degrees (`screening` only).
    #[arg(long, default_value_t = 39.1, allow_hyphen_values = true)]
    pub latitude_deg: f64,
    /// Print one JSON object instead of tables.
    #[arg(long)]
    pub json: bool,
}

struct SeedResult {
    /// Per checkpoint: (errors, covariance) of the converged estimate, and the single pass's errors.
    at: Vec<(DVector<f64>, DMatrix<f64>, DVector<f64>)>,
}

fn truncated(prep: &Prepared, hours: f64) -> Prepared {
    let measurements: Vec<Measurement> = prep
        .measurements
        .iter()
        .filter(|m| m.t_s <= hours * 3600.0 + 1e-6)
        .copied()
        .collect();
    Prepared {
        measurements,
        ..prep.clone()
    }
}

/// Runs the chosen benchmark.
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    // The longest run asked for must be one the simulator accepts (it panics otherwise).
    let mut longest = Scenario::paper();
    longest.hours = args.hours.iter().cloned().fold(0.0, f64::max);
    longest.rate_s = args.rate_s;
    longest.latitude_deg = args.latitude_deg;
    longest
        .validate()
        .map_err(|e| anyhow::anyhow!("--hours/--rate-s: {e}"))?;
    match args.what.as_str() {
        "calibration" => calibration(args),
        "sensitivity" => sensitivity(args),
        "screening" => screening(args),
        _ => accuracy(args),
    }
}

/// One candidate's result on one seed: name, p, Holm-adjusted p, largest detection limit in σ.
type CandidateP = (String, f64, f64, f64);

/// False alarms of the diagnosis on clean runs (paper model, no hidden effect): per candidate the
/// fraction of seeds with p < 1 %, and the family-wise rate after Holm's adjustment.
fn calibration(args: &BenchArgs) -> anyhow::Result<()> {
    use crate::diagnose::DiagnoseConfig;
    let hours = args.hours.iter().cloned().fold(0.0, f64::max);
    let t0 = std::time::Instant::now();
    let cfg = DiagnoseConfig::default();
    let pb = crate::progress::bar(args.seeds, "clean seeds");
    let per_seed: Vec<anyhow::Result<Vec<CandidateP>>> = (1..=args.seeds)
        .into_par_iter()
        .progress_with(pb.clone())
        .map(|seed| calibration_seed(args, seed, hours, &cfg))
        .collect();
    let per_seed: Vec<_> = per_seed.into_iter().collect::<anyhow::Result<_>>()?;
    let n = per_seed.len() as f64;
    let mut names: Vec<String> = per_seed
        .first()
        .map(|s| s.iter().map(|r| r.0.clone()).collect())
        .unwrap_or_default();
    names.sort();
    let mut rows = vec![];
    for name in &names {
        let ps: Vec<f64> = per_seed
            .iter()
            .filter_map(|s| s.iter().find(|r| &r.0 == name).map(|r| r.1))
            .collect();
        let below = |a: f64| ps.iter().filter(|p| **p < a).count();
        let mean_p = ps.iter().sum::<f64>() / ps.len() as f64;
        rows.push(serde_json::json!({ "candidate": name, "seeds": ps.len(), "below_0_01": below(0.01), "below_0_05": below(0.05), "below_0_10": below(0.10), "mean_p": mean_p }));
        if !args.json {
            println!(
                "{:<14} p<0.01: {:>2}/{} ({:>4.1} %)   p<0.05: {:>2} ({:>4.1} %)   p<0.10: {:>2} ({:>4.1} %)   mean p {:.2} (0.50 if uniform)",
                name,
                below(0.01),
                ps.len(),
                100.0 * below(0.01) as f64 / n,
                below(0.05),
                100.0 * below(0.05) as f64 / n,
                below(0.10),
                100.0 * below(0.10) as f64 / n,
                mean_p
            );
        }
    }
    let family = per_seed
        .iter()
        .filter(|s| s.iter().any(|r| r.0 != "(whiteness)" && r.2 < 0.01))
        .count();
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &serde_json::json!({ "seeds": args.seeds, "hours": hours, "candidates": rows, "family_wise_alarms": family })
            )?
        );
    } else {
        println!(
            "family-wise: {family}/{} clean seeds with any candidate significant at 1 % after Holm's adjustment; {:.1} s",
            args.seeds,
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// One clean seed of the calibration (seed 1000 + `seed`, `hours` long, temperature written):
/// every testable candidate's p, Holm-adjusted p and largest detection limit in σ, and the
/// whiteness test's p.
fn calibration_seed(
    args: &BenchArgs,
    seed: u64,
    hours: f64,
    cfg: &crate::diagnose::DiagnoseConfig,
) -> anyhow::Result<Vec<CandidateP>> {
    let mut sc = Scenario::paper();
    sc.seed = 1000 + seed;
    sc.hours = hours;
    sc.rate_s = args.rate_s;
    sc.write_temp = true;
    let sim = simulate(&sc);
    let samples: Vec<Sample> = sim
        .samples
        .iter()
        .map(|s| Sample {
            t_s: s.t_s,
            specific_force: s.specific_force_mps2,
            temp_c: s.temp_c.unwrap_or(f64::NAN),
        })
        .collect();
    let site = estimator_core::Site::new(sc.latitude_deg, sc.gravity_mps2);
    let prep = prepare(site, &samples, &cfg.identify)?;
    let (d, _) = crate::diagnose::diagnose(&prep, Catalog::builtin(), &[catalog::paper()], cfg)?;
    Ok(d.ranking
        .iter()
        .filter(|c| c.untestable.is_none())
        .map(|c| {
            (
                c.effect.clone(),
                c.p_value,
                c.p_adjusted,
                c.params
                    .iter()
                    .map(|p| p.min_detectable / p.sigma.max(1e-300))
                    .fold(0.0, f64::max),
            )
        })
        .chain(std::iter::once((
            "(whiteness)".to_string(),
            d.whiteness.p_value,
            d.whiteness.p_value,
            0.0,
        )))
        .collect())
}

/// False alarms of the data-quality screening (what every command runs first) on clean runs of
/// the paper's scenario: per `--hours` value (each a run length, fractions allowed: 59.99, or
/// 60.0002778 for one sample more), seeds 1..=`--seeds` as `driftid simulate --seed N` makes
/// them; the runs with any finding and with one that makes the estimate untrusted (exit 3).
fn screening(args: &BenchArgs) -> anyhow::Result<()> {
    use crate::quality::Action;
    let t0 = std::time::Instant::now();
    let mut rows = vec![];
    for &hours in &args.hours {
        let pb = crate::progress::bar(args.seeds, "clean seeds");
        let per_seed: Vec<anyhow::Result<(u64, Vec<crate::quality::Finding>)>> = (1..=args.seeds)
            .into_par_iter()
            .progress_with(pb.clone())
            .map(|seed| {
                let mut sc = Scenario::paper();
                sc.seed = seed;
                sc.hours = hours;
                sc.rate_s = args.rate_s;
                sc.latitude_deg = args.latitude_deg;
                sc.accel_sigma_mps2 = 1e-5 * sc.gravity();
                let sim = simulate(&sc);
                let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
                let site = estimator_core::Site::new(sc.latitude_deg, sc.gravity_mps2);
                let prep = prepare(site, &samples, &Config::default())?;
                Ok((seed, prep.findings))
            })
            .collect();
        pb.finish_and_clear();
        let per_seed: Vec<_> = per_seed.into_iter().collect::<anyhow::Result<_>>()?;
        let any: Vec<&(u64, Vec<crate::quality::Finding>)> =
            per_seed.iter().filter(|(_, f)| !f.is_empty()).collect();
        let untrusting = any
            .iter()
            .filter(|(_, f)| {
                f.iter()
                    .any(|x| matches!(x.action, Action::NotRepaired | Action::Refused))
            })
            .count();
        let examples: Vec<String> = any
            .iter()
            .take(5)
            .map(|(seed, f)| format!("seed {seed}: {}", f[0].line()))
            .collect();
        if !args.json {
            println!(
                "{hours} h at {} s, {} deg: {}/{} clean seeds with a finding, {untrusting} untrusting{}",
                args.rate_s,
                args.latitude_deg,
                any.len(),
                args.seeds,
                if examples.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", examples.join("; "))
                }
            );
        }
        rows.push(serde_json::json!({ "hours": hours, "rate_s": args.rate_s, "latitude_deg": args.latitude_deg, "seeds": args.seeds, "with_finding": any.len(), "untrusting": untrusting, "examples": examples }));
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        println!("{:.1} s", t0.elapsed().as_secs_f64());
    }
    Ok(())
}

fn diagnose_run(sc: &Scenario) -> anyhow::Result<crate::diagnose::Diagnosis> {
    use crate::diagnose::{diagnose, DiagnoseConfig};
    let sim = simulate(sc);
    let samples: Vec<Sample> = sim
        .samples
        .iter()
        .map(|s| Sample {
            t_s: s.t_s,
            specific_force: s.specific_force_mps2,
            temp_c: s.temp_c.unwrap_or(f64::NAN),
        })
        .collect();
    let site = estimator_core::Site::new(sc.latitude_deg, sc.gravity_mps2);
    let cfg = DiagnoseConfig::default();
    let prep = prepare(site, &samples, &cfg.identify)?;
    Ok(diagnose(&prep, Catalog::builtin(), &[catalog::paper()], &cfg)?.0)
}

/// Detection limits checked empirically: for one parameter of each effect, the size the score
/// test should detect with 90 % power at 1 % (from a clean run's Fisher information), then the
/// detection rate over seeds at 1× and 2× that size.
fn sensitivity(args: &BenchArgs) -> anyhow::Result<()> {
    let hours = args.hours.iter().cloned().fold(0.0, f64::max);
    let mut base = Scenario::paper();
    base.hours = hours;
    base.rate_s = args.rate_s;
    base.write_temp = true;
    base.seed = 5000;
    let clean = diagnose_run(&base)?;
    // (effect, parameter, --effect pattern with X for the size)
    let cases = [
        ("g2", "GXxx-zz", "X,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0"),
        ("acc-bias", "BAx", "X,0,0"),
        ("acc-scale", "SAx", "X,0,0"),
        ("acc-misalign", "Mxy", "X,0,0,0,0,0"),
        ("drift-trend", "TX", "X,0,0"),
        ("temp-drift", "KX", "X,0,0"),
    ];
    let mut out = vec![];
    for (effect, param, pattern) in cases {
        let Some(p) = clean
            .ranking
            .iter()
            .find(|c| c.effect == effect)
            .and_then(|c| c.params.iter().find(|p| p.name == param))
        else {
            continue;
        };
        let size = p.min_detectable;
        for factor in [1.0, 2.0] {
            let spec = format!(
                "{effect}={}",
                pattern.replace('X', &format!("{:e}", size * factor))
            );
            let results: Vec<anyhow::Result<(bool, bool)>> = (1..=args.seeds)
                .into_par_iter()
                .map(|seed| {
                    let mut sc = base.clone();
                    sc.seed = 6000 + seed;
                    sc.effects = vec![spec.parse().map_err(|e: String| anyhow::anyhow!(e))?];
                    let d = diagnose_run(&sc)?;
                    let c = d
                        .ranking
                        .iter()
                        .find(|c| c.effect == effect)
                        .ok_or_else(|| anyhow::anyhow!("{effect} missing from the ranking"))?;
                    Ok((
                        c.p_adjusted < 0.01,
                        d.ranking[0].effect == effect && c.p_adjusted < 0.01,
                    ))
                })
                .collect();
            let r: Vec<(bool, bool)> = results.into_iter().collect::<anyhow::Result<_>>()?;
            let detected = r.iter().filter(|x| x.0).count();
            let first = r.iter().filter(|x| x.1).count();
            if !args.json {
                println!(
                    "{effect:<13} {param:<8} {factor}× predicted limit = {:.3e} {:<16}: detected {detected}/{} (ranked first {first}/{})",
                    size * factor,
                    p.unit,
                    args.seeds,
                    args.seeds
                );
            }
            out.push(serde_json::json!({ "effect": effect, "param": param, "unit": p.unit, "size": size * factor, "factor": factor,
                "detected": detected, "ranked_first": first, "seeds": args.seeds }));
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    }
    Ok(())
}

/// Runs the accuracy benchmark.
fn accuracy(args: &BenchArgs) -> anyhow::Result<()> {
    let max_h = args.hours.iter().cloned().fold(0.0, f64::max);
    let cfg = Config::default();
    let effects = vec![catalog::paper()];
    let t0 = std::time::Instant::now();
    let pb = crate::progress::bar(args.seeds, "seeds");
    let results: Vec<anyhow::Result<SeedResult>> = (1..=args.seeds)
        .into_par_iter()
        .progress_with(pb.clone())
        .map(|seed| accuracy_seed(args, seed, max_h, &effects, &cfg))
        .collect();
    let results: Vec<SeedResult> = results.into_iter().collect::<anyhow::Result<_>>()?;
    let elapsed = t0.elapsed().as_secs_f64();
    // The bound at the truth, per checkpoint (noise-free trajectory; the same for every seed).
    let sc = Scenario::paper();
    let truth = sc.coefficients;
    let site = estimator_core::Site::new(sc.latitude_deg, sc.gravity_mps2);
    let model = build_model(site, &effects, &cfg)?;
    let names: Vec<&str> = (3..15).map(|i| model.param(i).name).collect();
    let mut report = vec![];
    for (c, &h) in args.hours.iter().enumerate() {
        let bound = try_cramer_rao_bound(&model, &bound_geometry(site, h), &truth)?;
        let at = AccuracyAt::over_seeds(&results, c, &bound, &truth);
        if !args.json {
            at.print(h, args.seeds, &names, &bound);
        }
        report.push(serde_json::json!({ "hours": h, "rms_error": at.rms, "bound": bound, "ratio": at.ratios, "rms_ratio": at.rms_ratio,
            "worst_percent": at.worst_all, "nees_mean": at.nees, "nees_band95": [at.band.0, at.band.1], "single_pass_rms_error": at.rms_single }));
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &serde_json::json!({ "seeds": args.seeds, "coefficients": names, "checkpoints": report, "seconds": elapsed })
            )?
        );
    } else {
        println!(
            "\n{} seeds in {:.1} s on {} threads",
            args.seeds,
            elapsed,
            rayon::current_num_threads()
        );
    }
    Ok(())
}

/// One seed of the accuracy benchmark: the paper's scenario simulated for `max_h` hours,
/// identified on its first `--hours` of each checkpoint; the errors against the truth.
fn accuracy_seed(
    args: &BenchArgs,
    seed: u64,
    max_h: f64,
    effects: &[&dyn estimator_core::Effect],
    cfg: &Config,
) -> anyhow::Result<SeedResult> {
    let mut sc = Scenario::paper();
    sc.seed = seed;
    sc.hours = max_h;
    sc.rate_s = args.rate_s;
    let sim = simulate(&sc);
    let truth = DVector::from_row_slice(&sim.truth.coefficient_array());
    let samples: Vec<Sample> = sim
        .samples
        .iter()
        .map(|s| Sample {
            t_s: s.t_s,
            specific_force: s.specific_force_mps2,
            temp_c: f64::NAN,
        })
        .collect();
    let site = estimator_core::Site::new(sc.latitude_deg, sc.gravity_mps2);
    let model = build_model(site, effects, cfg)?;
    let prep = prepare(site, &samples, cfg)?;
    let mut at = vec![];
    for &h in &args.hours {
        let id = identify(&model, &truncated(&prep, h), cfg)?;
        let best = id.best();
        at.push((
            DVector::from_row_slice(&best.value) - &truth,
            best.cov.clone(),
            DVector::from_row_slice(
                &id.single_pass
                    .as_ref()
                    .ok_or_else(|| anyhow::anyhow!("the paper's single EKF pass diverged"))?
                    .value,
            ) - &truth,
        ));
    }
    Ok(SeedResult { at })
}

/// The measurement geometry of an `h`-hour level run for the Cramér–Rao bound: mean-time tags
/// of 60-s windows of 1-s samples (the bound needs only the geometry, not the values).
fn bound_geometry(site: estimator_core::Site, h: f64) -> Prepared {
    let meas: Vec<Measurement> = (0..)
        .map(|k| Measurement {
            t_s: 60.0 * k as f64 + 29.5,
            specific_force: [0.0; 3],
            temp_c: f64::NAN,
            count: 60,
            variance: [(1e-5 * site.gravity_mps2).powi(2); 3],
            time_var_s2: (60.0f64 * 60.0 - 1.0) / 12.0,
        })
        .take_while(|m| m.t_s <= h * 3600.0)
        .collect();
    Prepared::level(site, meas, [1e-5 * site.gravity_mps2; 3])
}

/// The accuracy at one checkpoint over the seeds: RMS errors against the bound, the worst
/// relative error and the mean NEES with its 95 % band.
struct AccuracyAt {
    rms: Vec<f64>,
    rms_single: Vec<f64>,
    worst: [f64; 12],
    ratios: Vec<f64>,
    rms_ratio: f64,
    worst_all: f64,
    nees: f64,
    band: (f64, f64),
}

impl AccuracyAt {
    /// Checkpoint `c` of every seed's `results`, against `bound` and the `truth`.
    fn over_seeds(results: &[SeedResult], c: usize, bound: &[f64], truth: &[f64]) -> Self {
        let n = results.len() as f64;
        let mut rms = [0.0; 12];
        let mut rms_single = [0.0; 12];
        let mut worst = [0.0f64; 12];
        let mut nees = 0.0;
        for r in results {
            let (e, p, es) = &r.at[c];
            for k in 0..12 {
                rms[k] += e[k] * e[k] / n;
                rms_single[k] += es[k] * es[k] / n;
                worst[k] = worst[k].max((e[k] / truth[k]).abs() * 100.0);
            }
            nees += p
                .clone()
                .cholesky()
                .map(|ch| e.dot(&ch.solve(e)))
                .unwrap_or(f64::NAN)
                / n;
        }
        let dof = 12.0 * n;
        let band = (chi2_quantile(0.025, dof) / n, chi2_quantile(0.975, dof) / n);
        let rms: Vec<f64> = rms.iter().map(|v| v.sqrt()).collect();
        let rms_single: Vec<f64> = rms_single.iter().map(|v| v.sqrt()).collect();
        let ratios: Vec<f64> = rms.iter().zip(bound).map(|(r, b)| r / b).collect();
        let rms_ratio = (ratios.iter().map(|r| r * r).sum::<f64>() / 12.0).sqrt();
        let worst_all = worst.iter().cloned().fold(0.0, f64::max);
        AccuracyAt {
            rms,
            rms_single,
            worst,
            ratios,
            rms_ratio,
            worst_all,
            nees,
            band,
        }
    }

    /// The checkpoint's table (`h` hours, `seeds` runs) and its summary line.
    fn print(&self, h: f64, seeds: u64, names: &[&str], bound: &[f64]) {
        println!("\n== {h} h ({seeds} seeds) ==");
        println!(
            "{:<5} {:>11} {:>11} {:>7} {:>9} {:>12}",
            "coef", "RMS error", "CRB 1σ", "ratio", "worst %", "1-pass RMS"
        );
        for k in 0..12 {
            println!(
                "{:<5} {:>11.3e} {:>11.3e} {:>7.2} {:>9.3} {:>12.3e}",
                names[k], self.rms[k], bound[k], self.ratios[k], self.worst[k], self.rms_single[k]
            );
        }
        let (nees, band) = (self.nees, self.band);
        println!(
            "RMS(ratio) {:.2}, max ratio {:.2}; worst coefficient error {:.3} %; mean NEES {:.2} (12 states; 95% band for the mean of {} seeds [{:.2}, {:.2}]) {}",
            self.rms_ratio,
            self.ratios.iter().cloned().fold(0.0, f64::max),
            self.worst_all,
            nees,
            seeds,
            band.0,
            band.1,
            if nees >= band.0 && nees <= band.1 { "inside" } else { "OUTSIDE" }
        );
    }
}
