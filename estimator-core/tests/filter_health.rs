//! Filter health: bad measurements, time order, innovation gating, never NaN.

use estimator_core::filter::{FilterError, Gate};
use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::{Ekf, Measurement, Model, Propagation, Site, PAPER_EFFECTS};

fn filter() -> Ekf<'static, 15> {
    let model = Model::new(
        Site::new(39.1, None),
        &PAPER_EFFECTS,
        arw_deg2ph_to_rad2ps(1e-8),
        Propagation::default(),
    )
    .unwrap();
    Ekf::with_default_prior(model).unwrap()
}

fn at_rest(t_s: f64, g: f64) -> Measurement {
    // At t ≈ 0 the platform has barely turned: the accelerometers read ~[0, 0, g].
    Measurement {
        t_s,
        specific_force: [0.0, 0.0, g],
        temp_c: f64::NAN,
        count: 60,
        variance: [1e-8; 3],
        time_var_s2: 0.0,
    }
}

#[test]
fn nan_and_non_increasing_time_are_refused_and_leave_the_filter_unchanged() {
    let mut f = filter();
    let g = f.model().site().gravity_mps2;
    f.step(&at_rest(30.0, g)).unwrap();
    let before = (f.state().to_vec(), f.cov(0, 0), f.time_s(), f.steps());
    let mut bad = at_rest(90.0, g);
    bad.specific_force[1] = f64::NAN;
    assert_eq!(f.step(&bad), Err(FilterError::BadMeasurement { step: 1 }));
    assert!(
        matches!(
            f.step(&at_rest(30.0, g)),
            Err(FilterError::TimeNotIncreasing { .. })
        ),
        "duplicate time"
    );
    assert!(
        matches!(
            f.step(&at_rest(10.0, g)),
            Err(FilterError::TimeNotIncreasing { .. })
        ),
        "out of order"
    );
    let mut zero_var = at_rest(90.0, g);
    zero_var.variance[0] = 0.0;
    assert!(matches!(
        f.step(&zero_var),
        Err(FilterError::BadMeasurement { .. })
    ));
    assert_eq!(
        before,
        (f.state().to_vec(), f.cov(0, 0), f.time_s(), f.steps())
    );
}

#[test]
fn gate_rejects_outliers_counts_them_and_faults_on_a_run() {
    let mut f = filter();
    let g = f.model().site().gravity_mps2;
    f.step(&at_rest(30.0, g)).unwrap();
    f.set_gate(Some(Gate {
        nis_max: 27.88,
        max_run: 3,
    }));
    // 1 m/s² off while the prediction is known to ~3e-3 m/s² (wide prior, one step): NIS ~1e5.
    let mut outlier = at_rest(90.0, g);
    outlier.specific_force[0] += 1.0;
    let x_before = f.state().to_vec();
    let r = f.step(&outlier).unwrap();
    assert!(r.rejected && r.nis > 1e4, "{r:?}");
    assert_eq!(f.rejected(), 1);
    // Only the prediction moved the state: the coefficients are untouched by the outlier.
    assert_eq!(&f.state()[3..], &x_before[3..]);
    outlier.t_s = 150.0;
    assert!(f.step(&outlier).unwrap().rejected);
    outlier.t_s = 210.0;
    assert_eq!(
        f.step(&outlier),
        Err(FilterError::RejectionRun { step: 3, count: 3 })
    );
    assert!(f.state().iter().all(|v| v.is_finite()));
}
