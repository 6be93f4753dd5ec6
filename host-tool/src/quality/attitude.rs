//! The initial platform orientation from the data, for a recording that does not state it
//! (no `initial_orientation_deg` line) and does not start level.
//!
//! Seen from the space-stable platform, the local vertical turns about the Earth's axis at the
//! Earth's rate: over the first hours the measured gravity direction u(t) sweeps an arc of a cone
//! whose axis is the pole in platform axes, `k_p`. The plane through the arc gives `k_p` (up to
//! sign); the first direction gives the vertical; the two fix the orientation P = C_0^p(0) by
//! TRIAD (P·k = k_p exactly, P·up nearest u(0)). The sign of `k_p` is the one whose predicted
//! sweep, `u(t) = P·R_k(Ωt)·up`, matches the data. If neither does, the axes are not a rotation of
//! a platform frame (an inverted axis, swapped columns) or the time axis is wrong: no estimate.
//!
//! Accuracy: the gyro drift adds its own turn to the Earth's, tilting the fitted axis by about
//! drift/Ω — up to ~7° for the paper's coefficients (D0 = 0.5 deg/h, g·Dj ≈ 1 deg/h, against
//! 15 deg/h) — so the estimate enters the filter with a 1σ of [`START_SIGMA_RAD`] and the filter
//! refines it together with the drift coefficients.

use estimator_core::frames::{euler_zyx, Site};
use estimator_core::robust;
use estimator_core::units::EARTH_RATE_RADPS;
use estimator_core::Sample;
use nalgebra::{Matrix3, Rotation3, SymmetricEigen, Unit, Vector3};

/// Span of the data used, h: long enough to sweep tens of degrees, short enough that the drift
/// turn stays a few degrees.
pub(crate) const FIT_HOURS: f64 = 6.0;
/// Shortest span that can fix the azimuth, h (a 30° arc of Earth rotation).
pub(crate) const MIN_FIT_HOURS: f64 = 2.0;
/// Largest RMS angle (rad) between the fitted sweep and the data (drift of ≤ 2 deg/h over the
/// span, plus margin); a reflected frame misses by tens of degrees.
pub(crate) const MAX_FIT_RMS_RAD: f64 = 0.1;
/// 1σ of each initial angle given to the filter, rad (8.6°: a drift of 2 deg/h against the
/// Earth's 15 deg/h).
pub const START_SIGMA_RAD: f64 = 0.15;

/// An initial orientation estimated from the data.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StartEstimate {
    /// ENU Euler angles (tx, ty, tz), rad.
    pub theta_enu: [f64; 3],
    /// RMS angle between the fitted sweep and the data, rad.
    pub fit_rms_rad: f64,
}

/// Robust gravity directions (per-axis medians, normalised) of `blocks` equal time blocks over
/// the first `hours`, with their mean times.
fn directions(samples: &[Sample], hours: f64, blocks: usize) -> Vec<(f64, Vector3<f64>)> {
    let t0 = samples.first().map_or(0.0, |s| s.t_s);
    let span = hours * 3600.0;
    let mut out = vec![];
    let mut start = 0;
    for b in 0..blocks {
        let end_t = t0 + span * (b + 1) as f64 / blocks as f64;
        let end = start + samples[start..].partition_point(|s| s.t_s < end_t);
        let chunk: Vec<&Sample> = samples[start..end]
            .iter()
            .filter(|s| s.specific_force.iter().all(|v| v.is_finite()))
            .collect();
        start = end;
        if chunk.len() < 3 {
            continue;
        }
        let median = |i: usize| {
            let mut v: Vec<f64> = chunk.iter().map(|s| s.specific_force[i]).collect();
            robust::median(&mut v)
        };
        let a = Vector3::new(median(0), median(1), median(2));
        let t = chunk.iter().map(|s| s.t_s - t0).sum::<f64>() / chunk.len() as f64;
        if a.norm() > 0.0 {
            out.push((t, a.normalize()));
        }
    }
    out
}

/// P with P·k = k_p and P·up1 closest to u1 (TRIAD, k primary).
fn triad(
    k: &Vector3<f64>,
    up1: &Vector3<f64>,
    k_p: &Vector3<f64>,
    u1: &Vector3<f64>,
) -> Option<Matrix3<f64>> {
    let m = k.cross(up1).try_normalize(1e-9)?;
    let m_p = k_p.cross(u1).try_normalize(1e-9)?;
    let frame = Matrix3::from_columns(&[*k, m, k.cross(&m)]);
    let frame_p = Matrix3::from_columns(&[*k_p, m_p, k_p.cross(&m_p)]);
    Some(frame_p * frame.transpose())
}

/// Estimates the initial orientation (see the module docs), or says why it cannot.
pub(crate) fn estimate_start(site: &Site, samples: &[Sample]) -> Result<StartEstimate, String> {
    let (t_first, t_last) = match (samples.first(), samples.last()) {
        (Some(a), Some(b)) => (a.t_s, b.t_s),
        _ => return Err("no samples".into()),
    };
    let hours = ((t_last - t_first) / 3600.0).min(FIT_HOURS);
    if hours < MIN_FIT_HOURS {
        return Err(format!(
            "the run is {hours:.1} h long; at least {MIN_FIT_HOURS} h are needed to find the azimuth from the Earth's turn"
        ));
    }
    let dirs = directions(samples, hours, 72);
    if dirs.len() < 12 {
        return Err("too few valid samples in the first hours".into());
    }
    let mean = dirs.iter().fold(Vector3::zeros(), |a, (_, u)| a + u) / dirs.len() as f64;
    let scatter = dirs.iter().fold(Matrix3::zeros(), |acc, (_, u)| {
        let d = u - mean;
        acc + d * d.transpose()
    });
    let eig = SymmetricEigen::new(scatter);
    let order = {
        let mut o = [0usize, 1, 2];
        o.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        o
    };
    let normal: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
    let k = site.polar_axis_0();
    let up = Vector3::new(0.0, 0.0, 1.0);
    let (t1, u1) = dirs[0];
    let turn = |t: f64| Rotation3::from_axis_angle(&Unit::new_unchecked(k), EARTH_RATE_RADPS * t);
    let up1 = turn(t1) * up;
    let mut best: Option<(f64, Matrix3<f64>)> = None;
    for sign in [1.0, -1.0] {
        let k_p = normal * sign;
        let Some(p) = triad(&k, &up1, &k_p, &u1) else {
            continue;
        };
        let ss: f64 = dirs
            .iter()
            .map(|(t, u)| {
                let pred = p * (turn(*t) * up);
                let a = pred.cross(u).norm().atan2(pred.dot(u));
                a * a
            })
            .sum();
        let rms = (ss / dirs.len() as f64).sqrt();
        if best.as_ref().is_none_or(|(r, _)| rms < *r) {
            best = Some((rms, p));
        }
    }
    let Some((rms, p)) = best else {
        return Err("gravity does not turn about a fixed axis".into());
    };
    if rms > MAX_FIT_RMS_RAD {
        return Err(format!(
            "no platform orientation explains how gravity turns in the first {hours:.1} h (best fit misses by {:.1} deg RMS): \
             an inverted axis or swapped columns (a mirror image of a platform frame), a wrong time unit or latitude",
            rms.to_degrees()
        ));
    }
    Ok(StartEstimate {
        theta_enu: euler_zyx(&p),
        fit_rms_rad: rms,
    })
}

/// Angle (deg) between the first `period_s` of specific force (per-axis medians) and +z.
pub(crate) fn start_tilt_deg(samples: &[Sample], period_s: f64) -> f64 {
    let hours = period_s.max(1e-9) / 3600.0;
    directions(samples, hours, 1)
        .first()
        .map_or(0.0, |(_, u)| u.z.clamp(-1.0, 1.0).acos().to_degrees())
}
