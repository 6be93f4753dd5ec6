//! The sense of the platform's turn: on a static base gravity circles the Earth's axis in the
//! space-stable platform frame, counter-clockwise seen from the north pole. The circle's axis,
//! oriented by that sense, makes the angle 90° − latitude with the start's vertical, so its sign
//! is the hemisphere's. A recording whose data turn as in the other hemisphere than its latitude
//! says has the latitude's sign wrong or a left-handed frame (an axis written with its sign
//! flipped, two axes swapped): either way the filter cannot fit it, and it is refused by name.

use estimator_core::units::RAD_PER_DEG;
use estimator_core::{Sample, Site};
use nalgebra::{Matrix3, Vector3};

use super::physics::Refuse;
use super::Kind;

/// Smallest sweep of gravity's direction that orients the circle, rad (10°: about 45 min of the
/// Earth's turn at mid latitudes; a block mean's direction is good to ~1e-5 rad).
const MIN_SWEEP_RAD: f64 = 10.0 * RAD_PER_DEG;
/// Latitudes (stated and from the data) nearer the equator than this are not judged, deg: there
/// the circle is nearly a great circle and its axis's tilt is within what the drift moves
/// (~1 deg/h of drift against 15 deg/h of the Earth's turn: a few degrees).
const MIN_LATITUDE_DEG: f64 = 10.0;

/// The latitude the data's turn gives, deg (`None` when the run sweeps too little).
pub(crate) fn latitude_from_turn(samples: &[Sample]) -> Option<f64> {
    latitude_from_forces(samples, |s| s.specific_force)
}

/// [`latitude_from_turn`] of the specific forces `force` reads from `items` in time order
/// (samples or filter-period means); read in place: a copy of a 60-h run's forces was 5 MB of
/// fresh memory, most of this check's time.
pub(crate) fn latitude_from_forces<T>(items: &[T], force: impl Fn(&T) -> [f64; 3]) -> Option<f64> {
    if items.len() < 16 {
        return None;
    }
    let blocks = 200.min(items.len() / 4).max(3);
    let per = items.len() / blocks;
    let u: Vec<Vector3<f64>> = (0..blocks)
        .map(|k| {
            items[k * per..(k + 1) * per]
                .iter()
                .fold(Vector3::zeros(), |acc, f| acc + Vector3::from(force(f)))
                .normalize()
        })
        .collect();
    let swept = u.iter().map(|v| v.angle(&u[0])).fold(0.0, f64::max);
    if !swept.is_finite() || swept < MIN_SWEEP_RAD {
        return None;
    }
    // The circle's plane: the direction of least scatter of the points about their mean.
    let mean = u.iter().sum::<Vector3<f64>>() / u.len() as f64;
    let scatter: Matrix3<f64> = u.iter().map(|v| (v - mean) * (v - mean).transpose()).sum();
    let eig = scatter.symmetric_eigen();
    let k = eig.eigenvalues.imin();
    let mut axis: Vector3<f64> = eig.eigenvectors.column(k).into_owned();
    // Oriented so that the points turn counter-clockwise about it.
    let sense: f64 = u.windows(2).map(|w| w[0].cross(&w[1]).dot(&axis)).sum();
    if sense < 0.0 {
        axis = -axis;
    }
    Some(u[0].dot(&axis).clamp(-1.0, 1.0).asin() / RAD_PER_DEG)
}

/// Whether the data's turn (`seen`, deg) confirms the hemisphere of the `stated` latitude: both
/// far enough from the equator to be judged, and of one sign.
pub(crate) fn confirms(stated: f64, seen: f64) -> bool {
    stated.abs() >= MIN_LATITUDE_DEG && seen.abs() >= MIN_LATITUDE_DEG && stated * seen > 0.0
}

/// Refuses a recording that turns as in the other hemisphere than its stated latitude.
pub(crate) fn check_hemisphere(site: &Site, samples: &[Sample]) -> Result<(), Refuse> {
    let stated = site.latitude_rad / RAD_PER_DEG;
    let Some(seen) = latitude_from_turn(samples) else {
        return Ok(());
    };
    if stated.abs() < MIN_LATITUDE_DEG || seen.abs() < MIN_LATITUDE_DEG || confirms(stated, seen) {
        return Ok(());
    }
    Err((
        Kind::OtherHemisphere,
        format!(
            "gravity turns in the platform frame as at latitude {seen:.0}°, not {stated}° as stated: \
             the latitude's sign is wrong, or the frame is left-handed (an accelerometer axis \
             written with its sign flipped, or two axes swapped); correct the metadata or the \
             columns"
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::{simulate, Fault, Scenario};

    fn samples(sc: &Scenario, faults: &[Fault]) -> Vec<Sample> {
        let mut sim = simulate(sc);
        for f in faults {
            f.apply(&mut sim.samples);
        }
        sim.samples.iter().map(Sample::from).collect()
    }

    /// The turn gives the latitude's sign and roughly its size (the drift of the paper's
    /// coefficients tilts the circle by a few degrees: 5° tolerance) in both hemispheres, and
    /// a flipped axis reverses it.
    #[test]
    fn the_turn_gives_the_hemisphere_and_a_flipped_axis_reverses_it() {
        for lat in [39.1, -30.0, 60.0] {
            let mut sc = Scenario::paper();
            sc.hours = 12.0;
            sc.rate_s = 10.0;
            sc.latitude_deg = lat;
            let clean = samples(&sc, &[]);
            let seen = latitude_from_turn(&clean).unwrap();
            assert!((seen - lat).abs() < 5.0, "{lat}: {seen}");
            let site = Site::new(lat, None);
            assert!(check_hemisphere(&site, &clean).is_ok());
            let flipped = samples(&sc, &[Fault::Flip { axis: 1 }]);
            assert!((latitude_from_turn(&flipped).unwrap() + lat).abs() < 5.0);
            let err = check_hemisphere(&site, &flipped).unwrap_err();
            assert_eq!(err.0, Kind::OtherHemisphere);
        }
    }
}
