//! The recording against physics: gravity's magnitude (metadata, units) and its direction at the
//! start (a level platform sees +g on z; an inverted or swapped axis does not).

use estimator_core::model::ANGLES;
use estimator_core::propagate::propagate_state;
use estimator_core::units::RAD_PER_DEG;
use estimator_core::{Model, Propagation, Sample, Site, PAPER_EFFECTS};
use nalgebra::Vector3;
use std::borrow::Cow;

use super::{Action, Finding, Kind};
use crate::recording::GRAVITY_RANGE_MPS2;

/// A refusal: finding kind and message.
pub(crate) type Refuse = (Kind, String);

/// Relative disagreement of the measured |A| with the metadata gravity beyond which the metadata
/// is wrong: accelerometer scale-factor errors are 1e-5–1e-4, so 1e-3 is far outside them.
pub(crate) const GRAVITY_REL_TOL: f64 = 1e-3;
/// Standard gravity, m/s² (the unit "g").
pub(crate) const STANDARD_GRAVITY: f64 = 9.806_65;
/// Largest tilt at the start that is levelled (beyond: an axis inverted or swapped, or the
/// platform far from level), deg.
pub(crate) const MAX_START_TILT_DEG: f64 = 10.0;
/// A start tilt is levelled when it exceeds this many 1σ of its own uncertainty.
pub(crate) const TILT_SIGMAS: f64 = 6.0;

fn mean_magnitude(samples: &[Sample]) -> f64 {
    let n = samples.len().max(1) as f64;
    samples
        .iter()
        .map(|s| Vector3::from(s.specific_force).norm())
        .sum::<f64>()
        / n
}

/// Mean |A| against the site's gravity: outputs in g are converted, a wrong metadata gravity is
/// replaced by the measured one, anything else is refused.
pub(crate) fn check_gravity(
    site: &mut Site,
    samples: &mut Cow<'_, [Sample]>,
    sigma: &mut [f64; 3],
    findings: &mut Vec<Finding>,
) -> Result<(), Refuse> {
    let mut m = mean_magnitude(samples);
    let g = site.gravity_mps2;
    if (m / STANDARD_GRAVITY - 1.0).abs() > 0.5 && (m - 1.0).abs() < 0.05 {
        for s in samples.to_mut().iter_mut() {
            for v in s.specific_force.iter_mut() {
                *v *= STANDARD_GRAVITY;
            }
        }
        for s in sigma.iter_mut() {
            *s *= STANDARD_GRAVITY;
        }
        findings.push(Finding {
            kind: Kind::UnitsG,
            message: format!(
                "mean |A| = {m:.6} in the file: the outputs are in g, not m/s^2; converted with 1 g = {STANDARD_GRAVITY} m/s^2"
            ),
            start_s: None,
            end_s: None,
            samples: samples.len(),
            action: Action::Repaired,
        });
        m *= STANDARD_GRAVITY;
    }
    let rel = m / g - 1.0;
    if rel.abs() <= GRAVITY_REL_TOL {
        return Ok(());
    }
    let (lo, hi) = GRAVITY_RANGE_MPS2;
    if (lo..=hi).contains(&m) {
        findings.push(Finding {
            kind: Kind::GravityMismatch,
            message: format!(
                "the mean specific-force magnitude is {m:.5} m/s^2 but the metadata gravity is {g:.5} m/s^2 \
                 (relative {rel:+.1e}; accelerometer scale errors are 1e-5–1e-4, so {GRAVITY_REL_TOL:.0e} is far beyond them): \
                 the metadata is wrong; the model uses the measured {m:.5} m/s^2"
            ),
            start_s: None,
            end_s: None,
            samples: samples.len(),
            action: Action::Repaired,
        });
        site.gravity_mps2 = m;
        Ok(())
    } else {
        Err((
            Kind::GravityMismatch,
            format!(
                "the mean specific-force magnitude is {m:.4} m/s^2, not gravity ({g:.4} m/s^2, or 1 if the outputs were in g): \
                 the accelerometer outputs have a wrong unit or scale"
            ),
        ))
    }
}

/// The refusal of a level start whose mean specific force `a` lies `tilt_deg` from +z over the
/// first `span_s` seconds: an inverted z, swapped columns, or a platform far from level.
fn far_from_level(a: &Vector3<f64>, tilt_deg: f64, span_s: f64) -> Refuse {
    let (ax, _) =
        a.iter().enumerate().fold(
            (0, 0.0),
            |best, (i, v)| {
                if v.abs() > best.1 {
                    (i, v.abs())
                } else {
                    best
                }
            },
        );
    let sign = if a[ax] < 0.0 { '-' } else { '+' };
    let what = match (ax, sign) {
        (2, '-') => "the z axis is inverted (or the platform is upside down)".to_string(),
        (2, _) => format!("the platform is tilted {tilt_deg:.1} deg from level"),
        _ => format!(
            "gravity lies along {sign}{}: columns swapped (e.g. {}↔z) or an inverted axis, or the platform is far from level",
            super::axis_name(ax),
            super::axis_name(ax)
        ),
    };
    (
        Kind::InitialOrientation,
        format!(
            "at the start (first {:.0} s) the specific force is [{:.4}, {:.4}, {:.4}] m/s^2, {tilt_deg:.1} deg from +z: {what}. \
             The model starts from a level platform (x east, y north, z up); fix the columns or signs of the recording",
            span_s,
            a.x,
            a.y,
            a.z
        ),
    )
}

/// The samples of the first filter period (at least the first four).
fn first_window(samples: &[Sample], period_s: f64) -> Vec<&Sample> {
    let t0 = samples.first().map(|s| s.t_s).unwrap_or(0.0);
    let window: Vec<&Sample> = samples
        .iter()
        .take_while(|s| s.t_s < t0 + period_s.max(1e-9))
        .collect();
    if window.len() < 4 {
        samples.iter().take(4).collect()
    } else {
        window
    }
}

/// The specific force the stated start `theta0` predicts at `t_mid` (s; the paper's model, no
/// drift, m/s²), its Jacobian (∂A/∂θ in the first three columns) and the drift prior's 1σ
/// (deg/h); `None` when the model cannot be built for `site`.
fn stated_start(
    site: &Site,
    theta0: [f64; 3],
    t_mid: f64,
) -> Option<(
    Vector3<f64>,
    [Vector3<f64>; estimator_core::model::MAX_STATES],
    f64,
)> {
    let model = Model::new(*site, &PAPER_EFFECTS, 0.0, Propagation::default()).ok()?;
    let mut x = vec![0.0; model.dim()];
    x[..ANGLES].copy_from_slice(&theta0);
    propagate_state::<{ estimator_core::model::MAX_STATES }>(&model, &mut x, 0.0, t_mid, 0.0, 0.0);
    let mut jac = [Vector3::zeros(); estimator_core::model::MAX_STATES];
    let pred = model.measurement(&x, t_mid, 0.0, 0.0, &mut jac);
    Some((pred, jac, model.param(ANGLES).prior_sigma))
}

/// Refuses a start whose measured specific force `a` (the first window's mean over `span_s`,
/// m/s²) is more than [`MAX_START_TILT_DEG`] from the stated orientation's prediction `pred`
/// (or, for a level start, from +z): the metadata, the columns or their signs are wrong.
fn start_within_reach(
    site: &Site,
    theta0: [f64; 3],
    a: &Vector3<f64>,
    pred: &Vector3<f64>,
    span_s: f64,
) -> Result<(), Refuse> {
    if theta0 != [0.0; 3] {
        let off_deg = a.angle(pred) / RAD_PER_DEG;
        if off_deg > MAX_START_TILT_DEG {
            let enu = site.angles_to_enu(&theta0);
            return Err((
                Kind::InitialOrientation,
                format!(
                    "at the start the specific force is [{:.4}, {:.4}, {:.4}] m/s^2, {off_deg:.1} deg from the [{:.4}, {:.4}, {:.4}] m/s^2 \
                     the metadata's initial orientation ({:.3}, {:.3}, {:.3} deg) predicts: the orientation metadata, the columns or their signs are wrong",
                    a.x, a.y, a.z, pred.x, pred.y, pred.z,
                    enu[0] / RAD_PER_DEG, enu[1] / RAD_PER_DEG, enu[2] / RAD_PER_DEG
                ),
            ));
        }
        return Ok(());
    }
    let tilt_deg = (a.z / a.norm()).clamp(-1.0, 1.0).acos() / RAD_PER_DEG;
    if tilt_deg > MAX_START_TILT_DEG {
        return Err(far_from_level(a, tilt_deg, span_s));
    }
    Ok(())
}

/// Where gravity points at the start. A level start (`theta0` = 0) sees +g on z, any other
/// initial orientation what the model predicts from `theta0` (after the Earth-rate turn of the
/// first window); a small departure is levelled (the returned angle correction, least-norm: the
/// rotation about gravity is not seen, the azimuth stays the alignment's), a large one or
/// gravity on another axis is refused.
pub(crate) fn check_start(
    site: &Site,
    samples: &[Sample],
    period_s: f64,
    sigma: &[f64; 3],
    theta0: [f64; 3],
    findings: &mut Vec<Finding>,
) -> Result<Option<([f64; 3], f64)>, Refuse> {
    let t0 = samples.first().map(|s| s.t_s).unwrap_or(0.0);
    let window = first_window(samples, period_s);
    let n = window.len() as f64;
    let t_mid = window.iter().map(|s| s.t_s).sum::<f64>() / n;
    let a = window.iter().fold(Vector3::zeros(), |acc, s| {
        acc + Vector3::from(s.specific_force)
    }) / n;
    // The prediction of the stated start at the window's mean time (no drift), and ∂A/∂θ there.
    let Some((pred, jac, drift_prior_degph)) = stated_start(site, theta0, t_mid) else {
        return Ok(None);
    };
    let span_s = window.last().map(|s| s.t_s).unwrap_or(t0) - t0;
    start_within_reach(site, theta0, &a, &pred, span_s)?;
    let d = a - pred;
    // Least-norm angle correction: A ≈ pred + J·δ; J has rank 2 (a turn about gravity is not
    // seen). For a level start this is tx = d_y/g, ty = −d_x/g, tz = 0.
    // A level start levels tx, ty only: the azimuth stays the alignment's (tz = 0 exactly).
    let level = theta0 == [0.0; 3];
    let j = nalgebra::Matrix3::from_columns(&[
        jac[0],
        jac[1],
        if level { Vector3::zeros() } else { jac[2] },
    ]);
    let Ok(pinv) = j.pseudo_inverse(1e-9 * site.gravity_mps2) else {
        return Ok(None);
    };
    let delta = pinv * d;
    let (tx, ty) = (delta.x, delta.y);
    let tilt = (j * delta).norm() / site.gravity_mps2;
    // Its 1σ: the window mean's noise, plus the platform turn a drift of the prior's size (1 deg/h
    // on each axis) makes before the window's mean time.
    let drift_radps = estimator_core::units::RADPS_PER_DEGPH * drift_prior_degph;
    let noise = sigma[0].max(sigma[1]) / n.sqrt() / site.gravity_mps2;
    let sigma_tilt = noise.hypot(drift_radps * (t_mid - 0.0).max(0.0)).max(1e-6);
    if tilt > TILT_SIGMAS * sigma_tilt {
        findings.push(Finding {
            kind: Kind::InitialTilt,
            message: format!(
                "the platform starts {:.3} deg from the stated orientation (correction tx {:+.4} deg, ty {:+.4} deg, 1σ {:.1e} deg): \
                 the initial state is levelled from the first window's gravity direction (azimuth from the alignment)",
                tilt / RAD_PER_DEG,
                tx / RAD_PER_DEG,
                ty / RAD_PER_DEG,
                sigma_tilt / RAD_PER_DEG
            ),
            start_s: Some(t0),
            end_s: window.last().map(|s| s.t_s),
            samples: window.len(),
            action: Action::Repaired,
        });
        return Ok(Some(([delta.x, delta.y, delta.z], sigma_tilt)));
    }
    Ok(None)
}
