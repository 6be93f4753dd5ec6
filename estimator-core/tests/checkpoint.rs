//! Checkpoints: resume gives bit-identical continuation; damaged, foreign or truncated images are
//! refused with the reason.

use estimator_core::checkpoint::{size, CheckpointError};
use estimator_core::effects::{AccBias, Effect, PaperDrift};
use estimator_core::units::arw_deg2ph_to_rad2ps;
use estimator_core::{Ekf, Measurement, Model, Propagation, Site, PAPER_EFFECTS};

fn model() -> Model<'static> {
    Model::new(
        Site::new(39.1, None),
        &PAPER_EFFECTS,
        arw_deg2ph_to_rad2ps(1e-8),
        Propagation::default(),
    )
    .unwrap()
}

/// Measurements from the filter's own noise-free prediction with a perturbation, so the filter
/// has something to do; what matters here is that two filters see the same sequence.
fn measurement(k: usize, g: f64) -> Measurement {
    let t = 60.0 * k as f64 + 30.0;
    let w = 7.292115e-5 * t;
    let f = [
        g * 0.6 * w.sin() + 1e-4 * (k as f64).cos(),
        g * 0.3 * (1.0 - w.cos()),
        g * (1.0 - 0.05 * (1.0 - w.cos())),
    ];
    Measurement {
        t_s: t,
        specific_force: f,
        temp_c: f64::NAN,
        count: 60,
        variance: [1e-8; 3],
        time_var_s2: 299.9,
    }
}

#[test]
fn resume_continues_bit_identically() {
    let g = Site::new(39.1, None).gravity_mps2;
    let mut a = Ekf::<15>::with_default_prior(model()).unwrap();
    for k in 0..50 {
        a.step(&measurement(k, g)).unwrap();
    }
    let mut image = [0u8; size(15)];
    assert_eq!(a.checkpoint(&mut image).unwrap(), size(15));
    let mut b = Ekf::<15>::with_default_prior(model()).unwrap();
    b.resume(&image).unwrap();
    assert_eq!(b.steps(), 50);
    for k in 50..80 {
        let (ra, rb) = (
            a.step(&measurement(k, g)).unwrap(),
            b.step(&measurement(k, g)).unwrap(),
        );
        assert_eq!(ra, rb, "step {k}");
    }
    assert_eq!(a.state(), b.state());
}

#[test]
fn bad_images_are_refused_and_leave_the_filter_unchanged() {
    let g = Site::new(39.1, None).gravity_mps2;
    let mut a = Ekf::<15>::with_default_prior(model()).unwrap();
    a.step(&measurement(0, g)).unwrap();
    let mut image = [0u8; size(15)];
    a.checkpoint(&mut image).unwrap();
    let mut fresh = Ekf::<15>::with_default_prior(model()).unwrap();
    let before = fresh.state().to_vec();
    for byte in [20usize, 100, 500, size(15) - 5] {
        let mut damaged = image;
        damaged[byte] ^= 0x10;
        assert_eq!(
            fresh.resume(&damaged),
            Err(CheckpointError::Crc),
            "flip at byte {byte}"
        );
    }
    assert_eq!(
        fresh.resume(&image[..size(15) - 1]),
        Err(CheckpointError::Truncated)
    );
    let mut other_version = image;
    other_version[4] = 9;
    assert!(matches!(
        fresh.resume(&other_version),
        Err(CheckpointError::Version {
            found: 9,
            expected: 1
        })
    ));
    let mut not_one = image;
    not_one[0] = b'X';
    assert_eq!(fresh.resume(&not_one), Err(CheckpointError::BadMagic));
    // Another model configuration: the paper's drift plus accelerometer bias.
    static WITH_BIAS: [&dyn Effect; 2] = [&PaperDrift, &AccBias];
    let m2 = Model::new(
        Site::new(39.1, None),
        &WITH_BIAS,
        arw_deg2ph_to_rad2ps(1e-8),
        Propagation::default(),
    )
    .unwrap();
    let mut other = Ekf::<18>::with_default_prior(m2).unwrap();
    assert!(matches!(
        other.resume(&image),
        Err(CheckpointError::ModelMismatch { .. })
    ));
    // Same effects, other latitude: also another configuration.
    let m3 = Model::new(
        Site::new(45.0, None),
        &PAPER_EFFECTS,
        arw_deg2ph_to_rad2ps(1e-8),
        Propagation::default(),
    )
    .unwrap();
    assert!(matches!(
        Ekf::<15>::with_default_prior(m3).unwrap().resume(&image),
        Err(CheckpointError::ModelMismatch { .. })
    ));
    assert_eq!(fresh.state(), &before[..]);
    assert_eq!(fresh.steps(), 0);
}

#[test]
fn crc32_matches_the_standard_check_value() {
    // The CRC-32/ISO-HDLC check value of "123456789".
    assert_eq!(estimator_core::checkpoint::crc32(b"123456789"), 0xCBF4_3926);
}
