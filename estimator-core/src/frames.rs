//! Frames and the platform attitude (model.md, "Frames").
//!
//! Frame 0 is local level east-north-up at the site, fixed to the Earth, set when the gyros
//! reach stable operation. The platform frame p is space-stable. `C = C_0^p(θ) = Rz(tz)·Ry(ty)·Rx(tx)`
//! with passive elementary rotations, θ = 0 at gyro start.

use nalgebra::{Matrix3, Vector3};

use crate::units::EARTH_RATE_RADPS;

/// Where the platform stands: latitude and local gravity.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Site {
    /// Geodetic latitude, rad.
    pub latitude_rad: f64,
    /// Magnitude of gravity, m/s².
    pub gravity_mps2: f64,
}

impl Site {
    /// A site at `latitude_deg`, with `gravity_mps2` or, if `None`, WGS-84 normal gravity there.
    pub fn new(latitude_deg: f64, gravity_mps2: Option<f64>) -> Self {
        let latitude_rad = latitude_deg * crate::units::RAD_PER_DEG;
        Site {
            latitude_rad,
            gravity_mps2: gravity_mps2.unwrap_or_else(|| normal_gravity(latitude_rad)),
        }
    }

    /// Earth rate in frame 0 (ENU), rad/s: `[0, Ω cos L, Ω sin L]`.
    pub fn earth_rate_0(&self) -> Vector3<f64> {
        let (s, c) = libm::sincos(self.latitude_rad);
        Vector3::new(0.0, EARTH_RATE_RADPS * c, EARTH_RATE_RADPS * s)
    }

    /// Specific force at rest in frame 0, m/s²: `[0, 0, +g]`.
    pub fn gravity_0(&self) -> Vector3<f64> {
        Vector3::new(0.0, 0.0, self.gravity_mps2)
    }
}

/// WGS-84 normal gravity on the ellipsoid (Somigliana), m/s². 9.800898 m/s² at 39.1° N.
pub fn normal_gravity(latitude_rad: f64) -> f64 {
    let s = libm::sin(latitude_rad);
    let s2 = s * s;
    9.780_325_335_9 * (1.0 + 0.001_931_852_652_41 * s2)
        / libm::sqrt(1.0 - 0.006_694_379_990_13 * s2)
}

/// The platform attitude C_0^p at θ with its partial derivatives ∂C/∂θ_j.
#[derive(Clone, Copy, Debug)]
pub struct Attitude {
    /// C_0^p: frame-0 vectors to platform axes.
    pub c: Matrix3<f64>,
    /// ∂C/∂tx, ∂C/∂ty, ∂C/∂tz.
    pub dc: [Matrix3<f64>; 3],
    /// sin and cos of (tx, ty, tz).
    pub sin: Vector3<f64>,
    /// cos of (tx, ty, tz).
    pub cos: Vector3<f64>,
}

impl Attitude {
    /// Attitude at Euler angles θ = (tx, ty, tz), rad.
    pub fn new(theta: &Vector3<f64>) -> Self {
        let (sx, cx) = libm::sincos(theta.x);
        let (sy, cy) = libm::sincos(theta.y);
        let (sz, cz) = libm::sincos(theta.z);
        // C = Rz·Ry·Rx multiplied out (Rx = [[1,0,0],[0,c,s],[0,-s,c]], …), and its partials.
        let (sxsy, cxsy) = (sx * sy, cx * sy);
        let row0 = Vector3::new(cy * cz, cx * sz + sxsy * cz, sx * sz - cxsy * cz);
        let row1 = Vector3::new(-cy * sz, cx * cz - sxsy * sz, sx * cz + cxsy * sz);
        let row2 = Vector3::new(sy, -sx * cy, cx * cy);
        let c = Matrix3::from_rows(&[row0.transpose(), row1.transpose(), row2.transpose()]);
        let d_tx = Matrix3::new(
            0.0,
            -sx * sz + cxsy * cz,
            cx * sz + sxsy * cz,
            0.0,
            -sx * cz - cxsy * sz,
            cx * cz - sxsy * sz,
            0.0,
            -cx * cy,
            -sx * cy,
        );
        let d_ty = Matrix3::new(
            -sy * cz,
            sx * cy * cz,
            -cx * cy * cz,
            sy * sz,
            -sx * cy * sz,
            cx * cy * sz,
            cy,
            sxsy,
            -cxsy,
        );
        // ∂/∂tz turns row 0 into row 1 and row 1 into −row 0.
        let d_tz = Matrix3::from_rows(&[
            row1.transpose(),
            -row0.transpose(),
            Vector3::zeros().transpose(),
        ]);
        Attitude {
            c,
            dc: [d_tx, d_ty, d_tz],
            sin: Vector3::new(sx, sy, sz),
            cos: Vector3::new(cx, cy, cz),
        }
    }

    /// Specific force along the platform axes when the base is at rest, `A = C·[0,0,g]`, m/s².
    pub fn specific_force(&self, g: f64) -> Vector3<f64> {
        self.c.column(2) * g
    }

    /// ∂A/∂θ_j, m/s² per rad.
    pub fn d_specific_force(&self, g: f64, j: usize) -> Vector3<f64> {
        self.dc[j].column(2) * g
    }
}
