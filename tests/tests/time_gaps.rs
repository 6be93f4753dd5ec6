//! A recording with gaps (a recorder restart, a link outage): the filter propagates across them
//! (RK4 in ≤ 60-s sub-steps) and the estimate stays consistent.

use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::{Model, Propagation, Sample, Site, PAPER_EFFECTS};
use host_tool::identify::{identify, prepare, Config};
use host_tool::simulate::{simulate, Scenario};

#[test]
fn identification_propagates_across_gaps() {
    let mut sc = Scenario::paper();
    sc.seed = 41;
    sc.rate_s = 10.0;
    let sim = simulate(&sc);
    // Two gaps: 2 h at 20–22 h and 25 min at 40 h.
    let gap = |t: f64| {
        (20.0 * 3600.0..22.0 * 3600.0).contains(&t)
            || (40.0 * 3600.0..40.0 * 3600.0 + 1500.0).contains(&t)
    };
    let samples: Vec<Sample> = sim
        .samples
        .iter()
        .filter(|s| !gap(s.t_s))
        .map(|s| Sample {
            t_s: s.t_s,
            specific_force: s.specific_force_mps2,
            temp_c: f64::NAN,
        })
        .collect();
    let site = Site::new(sc.latitude_deg, sc.gravity_mps2);
    let model = Model::new(
        site,
        &PAPER_EFFECTS,
        arw_deg2ph_to_rad2ps(1e-8),
        Propagation::default(),
    )
    .unwrap();
    let cfg = Config::default();
    let prep = prepare(site, &samples, &cfg).unwrap();
    assert_eq!(
        prep.measurements.len(),
        3601 - 120 - 25,
        "windows inside the gaps hold no sample and produce no update"
    );
    let id = identify(&model, &prep, &cfg).unwrap();
    let best = id.best();
    let truth = sim.truth.coefficient_array();
    for k in 0..12 {
        let z = (best.value[k] - truth[k]) / best.sigma(k);
        // Consistency, as in the paper-scenario test: every coefficient within 3σ.
        assert!(z.abs() < 3.0, "{}: {z:.2} σ", id.params[k].name);
    }
    // Mean NIS/3 of ~3450 updates: 1σ spread 0.014; ±0.1 flags only an inconsistent filter.
    assert!((id.nis_mean() - 1.0).abs() < 0.1, "NIS/3 {}", id.nis_mean());
}

/// The time unit is read from the Earth's turn of gravity (`quality::time::time_scale`). At a
/// high latitude the cone gravity sweeps is narrow (half-angle 90° − L) and the g-sensitive drift
/// narrows it further, so the sweep turns back before the formula's Ωτ = 2.5; the turned-back
/// chord once read as a rate 0.43× the Earth's and a clean 54-h run at 68° N was refused as "not
/// in seconds". In seconds the scale must be 1 within the drift's share of the horizontal Earth
/// rate (≈ 1 deg/h against 15·cos L deg/h: ≤ 20 % at 68°, 30 % at 75°), and the run accepted.
#[test]
fn high_latitude_runs_keep_their_seconds() {
    for (lat, seed) in [(66.0, 12), (68.0, 6), (75.0, 3)] {
        let mut sc = Scenario::paper();
        sc.seed = seed;
        sc.rate_s = 10.0;
        sc.hours = 54.0;
        sc.latitude_deg = lat;
        let sim = simulate(&sc);
        let samples: Vec<Sample> = sim.samples.iter().map(Sample::from).collect();
        let site = Site::new(lat, sc.gravity_mps2);
        let scale = host_tool::quality::time::time_scale(&site, &samples)
            .expect("a 54-h run sweeps enough to test the unit");
        let drift_share = 1.0 / (15.04 * lat.to_radians().cos());
        assert!(
            (scale - 1.0).abs() < drift_share,
            "{lat}°: time scale {scale:.3} (drift share {drift_share:.2})"
        );
        let prep = prepare(site, &samples, &Config::default())
            .unwrap_or_else(|e| panic!("{lat}°: clean run refused: {e:#}"));
        assert!(
            prep.findings.iter().all(|f| f.kind.name() != "time-units"),
            "{lat}°: {:?}",
            prep.findings
        );
    }
}
