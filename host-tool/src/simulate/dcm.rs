//! Small direction-cosine-matrix toolkit of the truth simulator. Written independently of the
//! estimator core on purpose: a bug in the filter's math must not hide in the truth.

use nalgebra::{Matrix3, Vector3};

/// Earth rotation rate, rad/s.
pub(crate) const EARTH_RATE_RADPS: f64 = 7.292115e-5;
/// deg/h → rad/s.
pub(crate) const RADPS_PER_DEG_H: f64 = std::f64::consts::PI / 180.0 / 3600.0;

/// Cross-product matrix: `skew(a) * b = a × b`.
pub(crate) fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// exp(−[φ×]) by Rodrigues' formula: the passive DCM of a frame turned by the rotation vector φ
/// (old-frame coordinates → new-frame coordinates). `passive(φ)·v = v − sinθ/θ (φ×v) + …`.
pub(crate) fn passive(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    if theta < 1e-300 {
        return Matrix3::identity();
    }
    let k = skew(phi);
    let a = theta.sin() / theta;
    let h = (0.5 * theta).sin() / theta;
    let b = 2.0 * h * h; // (1 − cos θ)/θ², without cancellation
    Matrix3::identity() - k * a + k * k * b
}

/// Earth frame 0 → inertial frame i (= frame 0 at t = 0) at time t. A vector fixed in the Earth
/// turns with it: in inertial coordinates it is rotated actively by Ω t about the polar axis
/// `n0` (a unit vector, the same in both frames), i.e. the passive DCM of the angle −Ω t.
pub(crate) fn c_0i(n0: &Vector3<f64>, t_s: f64) -> Matrix3<f64> {
    passive(&(n0 * (-EARTH_RATE_RADPS * t_s)))
}

/// C = Rz(tz)·Ry(ty)·Rx(tx) from Euler angles (rad), passive elementary rotations (the inverse
/// of [`euler_zyx`]).
pub(crate) fn from_euler_zyx(theta: &[f64; 3]) -> Matrix3<f64> {
    let (sx, cx) = theta[0].sin_cos();
    let (sy, cy) = theta[1].sin_cos();
    let (sz, cz) = theta[2].sin_cos();
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, cx, sx, 0.0, -sx, cx);
    let ry = Matrix3::new(cy, 0.0, -sy, 0.0, 1.0, 0.0, sy, 0.0, cy);
    let rz = Matrix3::new(cz, sz, 0.0, -sz, cz, 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

/// Euler angles (tx, ty, tz) of C = Rz(tz)·Ry(ty)·Rx(tx) (passive elementary rotations):
/// C[2][0] = sin ty, C[2][1] = −cos ty sin tx, C[2][2] = cos ty cos tx, C[1][0] = −sin tz cos ty,
/// C[0][0] = cos tz cos ty. Angles in (−π, π], ty in [−π/2, π/2].
pub(crate) fn euler_zyx(c: &Matrix3<f64>) -> [f64; 3] {
    let ty = c[(2, 0)].clamp(-1.0, 1.0).asin();
    let tx = (-c[(2, 1)]).atan2(c[(2, 2)]);
    let tz = (-c[(1, 0)]).atan2(c[(0, 0)]);
    [tx, ty, tz]
}

/// Wraps an angle to (−π, π].
pub(crate) fn wrap_pi(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut r = a % two_pi;
    if r > std::f64::consts::PI {
        r -= two_pi;
    } else if r <= -std::f64::consts::PI {
        r += two_pi;
    }
    r
}

/// One step of C ← ½(3I − C Cᵀ) C: pulls a nearly orthonormal matrix back to orthonormal.
pub(crate) fn reorthonormalize(c: &Matrix3<f64>) -> Matrix3<f64> {
    (Matrix3::identity() * 3.0 - c * c.transpose()) * c * 0.5
}

/// WGS-84 normal gravity (Somigliana), m/s², at geodetic latitude `lat_rad`.
pub(crate) fn normal_gravity(lat_rad: f64) -> f64 {
    let s2 = lat_rad.sin().powi(2);
    9.780_325_335_9 * (1.0 + 0.001_931_852_652_41 * s2) / (1.0 - 0.006_694_379_990_13 * s2).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rx(a: f64) -> Matrix3<f64> {
        let (s, c) = a.sin_cos();
        Matrix3::new(1.0, 0.0, 0.0, 0.0, c, s, 0.0, -s, c)
    }
    fn ry(a: f64) -> Matrix3<f64> {
        let (s, c) = a.sin_cos();
        Matrix3::new(c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c)
    }
    fn rz(a: f64) -> Matrix3<f64> {
        let (s, c) = a.sin_cos();
        Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0)
    }

    #[test]
    fn passive_matches_elementary_rotations() {
        for a in [1e-9, 0.3, -2.0, 3.1] {
            assert!((passive(&Vector3::new(a, 0.0, 0.0)) - rx(a)).norm() < 1e-15);
            assert!((passive(&Vector3::new(0.0, a, 0.0)) - ry(a)).norm() < 1e-15);
            assert!((passive(&Vector3::new(0.0, 0.0, a)) - rz(a)).norm() < 1e-15);
        }
    }

    #[test]
    fn euler_round_trip() {
        for &(x, y, z) in &[(0.1, -0.2, 0.3), (-3.0, 1.2, 2.9), (2.0, -1.4, -3.1)] {
            let c = rz(z) * ry(y) * rx(x);
            let e = euler_zyx(&c);
            assert!(
                (e[0] - x).abs() < 1e-12 && (e[1] - y).abs() < 1e-12 && (e[2] - z).abs() < 1e-12
            );
        }
    }

    #[test]
    fn earth_frame_rotates_eastward() {
        // After a quarter turn about the polar axis at the equator (n = y = north), a point on
        // the local vertical (up, z) has moved east (+x) in inertial coordinates.
        let n = Vector3::new(0.0, 1.0, 0.0);
        let t = std::f64::consts::FRAC_PI_2 / EARTH_RATE_RADPS;
        let up_i = c_0i(&n, t) * Vector3::new(0.0, 0.0, 1.0);
        assert!(
            (up_i - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12,
            "{up_i}"
        );
    }

    #[test]
    fn normal_gravity_at_tianjin() {
        assert!((normal_gravity(39.1f64.to_radians()) - 9.800898).abs() < 5e-7);
    }
}

#[cfg(test)]
mod euler_tests {
    use super::*;

    #[test]
    fn from_euler_inverts_euler_zyx() {
        let th = [0.3, -1.2, 2.5];
        let back = euler_zyx(&from_euler_zyx(&th));
        for i in 0..3 {
            assert!((back[i] - th[i]).abs() < 1e-12, "{back:?}");
        }
    }
}
