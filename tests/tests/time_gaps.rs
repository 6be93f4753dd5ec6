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
