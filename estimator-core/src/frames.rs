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
        Site { latitude_rad, gravity_mps2: gravity_mps2.unwrap_or_else(|| normal_gravity(latitude_rad)) }
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
    9.780_325_335_9 * (1.0 + 0.001_931_852_652_41 * s2) / libm::sqrt(1.0 - 0.006_694_379_990_13 * s2)
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

fn rx(s: f64, c: f64) -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, s, 0.0, -s, c)
}
fn drx(s: f64, c: f64) -> Matrix3<f64> {
    Matrix3::new(0.0, 0.0, 0.0, 0.0, -s, c, 0.0, -c, -s)
}
fn ry(s: f64, c: f64) -> Matrix3<f64> {
    Matrix3::new(c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c)
}
fn dry(s: f64, c: f64) -> Matrix3<f64> {
    Matrix3::new(-s, 0.0, -c, 0.0, 0.0, 0.0, c, 0.0, -s)
}
fn rz(s: f64, c: f64) -> Matrix3<f64> {
    Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0)
}
fn drz(s: f64, c: f64) -> Matrix3<f64> {
    Matrix3::new(-s, c, 0.0, -c, -s, 0.0, 0.0, 0.0, 0.0)
}

impl Attitude {
    /// Attitude at Euler angles θ = (tx, ty, tz), rad.
    pub fn new(theta: &Vector3<f64>) -> Self {
        let (sx, cx) = libm::sincos(theta.x);
        let (sy, cy) = libm::sincos(theta.y);
        let (sz, cz) = libm::sincos(theta.z);
        let (x, y, z) = (rx(sx, cx), ry(sy, cy), rz(sz, cz));
        let zy = z * y;
        Attitude {
            c: zy * x,
            dc: [zy * drx(sx, cx), z * dry(sy, cy) * x, drz(sz, cz) * y * x],
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
