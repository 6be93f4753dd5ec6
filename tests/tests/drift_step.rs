//! A gyro drift step (issue 27, item 2, the gyro half): found as an explanation with its time and
//! size (`host_tool::diagnose::drift_step`), on the paper scenario from the independent truth
//! simulator, 60 h at 10-s samples, with `drift-step=0,0.002,0:30` injected (0.002 deg/h on Y at
//! 30 h). The profile runs on the paper model's converged fit at the stated set-up, as
//! `driftid identify` runs it on a misfit.
//!
//! Tolerances:
//! - step time within ±0.25 h of 30 h: the profile's grid is the 60-s filter period, and the
//!   kink's time is set by when the turn rate's change shows against the noise; measured 29.99 h
//!   (seed 5) and 29.77 h (seed 6, a 4× smaller step), so 0.25 h leaves room without accepting a
//!   coarse-grid miss (0.5 h);
//! - each axis' size within 3σ of the truth (0.002 on Y, 0 on X and Z), σ the refit's 1σ:
//!   exceeded with probability 0.27 % per axis for a correct 1σ;
//! - evidence gain above 10 after the look-elsewhere penalty, the adoption rule of every effect.

use estimator_core::{Sample, Site};
use host_tool::catalog;
use host_tool::diagnose::drift_step::profile;
use host_tool::diagnose::DiagnoseConfig;
use host_tool::identify::{build_model, identify, prepare};
use host_tool::simulate::{simulate, InjectedEffect, Scenario};

#[test]
fn a_drift_step_is_found_with_its_time_and_size() {
    for seed in [5, 7] {
        let mut sc = Scenario::paper();
        sc.seed = seed;
        sc.rate_s = 10.0;
        let injected: InjectedEffect = "drift-step=0,0.002,0:30".parse().unwrap();
        sc.effects.push(injected);
        let sim = simulate(&sc);
        let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
        let cfg = DiagnoseConfig::default().identify;
        let prep = prepare(Site::new(sc.latitude_deg, sc.gravity_mps2), &samples, &cfg).unwrap();
        let effects = vec![catalog::paper()];
        let model = build_model(prep.site, &effects, &cfg).unwrap();
        let id = identify(&model, &prep, &cfg).unwrap();
        let s = profile(&prep, &effects, &cfg, &id).expect("a 60-h run is profiled");
        eprintln!("seed {seed}: {}", s.reason());
        assert!(
            (s.t0_h - 30.0).abs() <= 0.25,
            "seed {seed}: t0 {} h",
            s.t0_h
        );
        let truth = [0.0, 0.002, 0.0];
        for i in 0..3 {
            let z = (s.size_degph[i] - truth[i]) / s.sigma_degph[i];
            assert!(
                z.abs() <= 3.0,
                "seed {seed} axis {i}: z {z:.2}: {}",
                s.reason()
            );
        }
        assert!(s.evidence_gain > 10.0, "seed {seed}: {}", s.reason());
        assert_eq!(s.main_axis().0, 1, "seed {seed}: the step is on Y");
    }
}
