//! Frames and the platform attitude (model.md, "Frames").
//!
//! Frame 0 is local level east-north-up at the site, fixed to the Earth, set when the gyros
//! reach stable operation. The platform frame p is space-stable. `C = C_0^p(θ) = Rz(tz)·Ry(ty)·Rx(tx)`
//! with passive elementary rotations, θ = 0 at gyro start.
//!
//! **Charts.** The Euler angles are singular at ty = ±90°. A platform fixed in inertial space
//! turns, seen from the Earth, about the polar axis once a day, so from some initial orientations
//! (or at the equator) the angles relative to frame 0 pass through the singularity. Each run
//! therefore measures θ in a chart frame r, a fixed rotation `R` of frame 0 chosen from the start
//! orientation ([`Site::chart_for_start`]): `C_0^p = C(θ)·R`. Gravity and Earth rate are then
//! simply carried in frame r (`R·g0`, `R·w_e0`); the equations are otherwise unchanged and exact.
//! [`Chart::Enu`] (R = I) keeps the paper's angles; [`Chart::Polar`] puts the chart's x axis on
//! the polar axis, where ty stays at 90° − (angle between the platform z axis and the pole).

use nalgebra::{Matrix3, Vector3};

use crate::units::EARTH_RATE_RADPS;

/// The frame r in which a run's Euler angles are measured (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Chart {
    /// r = frame 0 (east-north-up): the paper's angles.
    #[default]
    Enu,
    /// r: x along the polar axis, y east, z = x × y (the chart for starts whose daily turn
    /// would pass near ty = ±90° in frame 0).
    Polar,
}

/// Largest |ty| (deg) the daily turn may reach in the ENU chart before [`Chart::Polar`] is chosen:
/// the remaining 30° leave room for the drift-induced turn of a long run (0.5 deg/h for 60 h).
pub const ENU_CHART_MAX_TY_DEG: f64 = 60.0;

/// Where the platform stands: latitude, local gravity and the chart of its angles.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Site {
    /// Geodetic latitude, rad.
    pub latitude_rad: f64,
    /// Magnitude of gravity, m/s².
    pub gravity_mps2: f64,
    /// Frame in which the platform angles θ are measured.
    pub chart: Chart,
}

impl Site {
    /// A site at `latitude_deg`, with `gravity_mps2` or, if `None`, WGS-84 normal gravity there.
    #[inline] // cold set-up: compiled in its (opt-level "z") caller in the firmware, issue 10
    pub fn new(latitude_deg: f64, gravity_mps2: Option<f64>) -> Self {
        let latitude_rad = latitude_deg * crate::units::RAD_PER_DEG;
        Site {
            latitude_rad,
            gravity_mps2: gravity_mps2.unwrap_or_else(|| normal_gravity(latitude_rad)),
            chart: Chart::Enu,
        }
    }

    /// The polar axis in frame 0 (unit): `[0, cos L, sin L]`.
    pub fn polar_axis_0(&self) -> Vector3<f64> {
        let (s, c) = crate::trig::sincos(self.latitude_rad);
        Vector3::new(0.0, c, s)
    }

    /// R: frame-0 vectors to chart-frame vectors.
    pub fn chart_rotation(&self) -> Matrix3<f64> {
        match self.chart {
            Chart::Enu => Matrix3::identity(),
            Chart::Polar => {
                let k = self.polar_axis_0();
                let east = Vector3::new(1.0, 0.0, 0.0);
                let third = k.cross(&east);
                Matrix3::from_rows(&[k.transpose(), east.transpose(), third.transpose()])
            }
        }
    }

    /// The chart for a run starting at ENU Euler angles `theta0_enu` (rad): [`Chart::Enu`] when the
    /// daily turn keeps |ty| ≤ [`ENU_CHART_MAX_TY_DEG`] there, else [`Chart::Polar`].
    ///
    /// In frame 0 the platform z axis circles the polar axis at a fixed angle β, and
    /// sin ty = z_p·(chart x axis): with the ENU chart (x east ⊥ pole) |ty| reaches min(β, 180°−β);
    /// with the polar chart ty stays 90° − β.
    pub fn chart_for_start(&self, theta0_enu: &[f64; 3]) -> Chart {
        let c0 = Attitude::new(&Vector3::from(*theta0_enu)).c;
        let z_p = c0.row(2).transpose();
        let cos_beta = z_p.dot(&self.polar_axis_0()).clamp(-1.0, 1.0);
        let sin_beta = sampling::sqrt(1.0 - cos_beta * cos_beta);
        let max_ty = libm::asin(sin_beta.min(1.0));
        if max_ty <= ENU_CHART_MAX_TY_DEG * crate::units::RAD_PER_DEG {
            Chart::Enu
        } else {
            Chart::Polar
        }
    }

    /// ENU Euler angles (rad) to this site's chart: θ_r with C(θ_r) = C(θ_enu)·Rᵀ.
    pub fn angles_to_chart(&self, theta_enu: &[f64; 3]) -> [f64; 3] {
        match self.chart {
            Chart::Enu => *theta_enu,
            _ => euler_zyx(
                &(Attitude::new(&Vector3::from(*theta_enu)).c * self.chart_rotation().transpose()),
            ),
        }
    }

    /// This site's chart angles (rad) to ENU Euler angles: C(θ_enu) = C(θ_r)·R.
    pub fn angles_to_enu(&self, theta_r: &[f64; 3]) -> [f64; 3] {
        match self.chart {
            Chart::Enu => *theta_r,
            _ => euler_zyx(&(Attitude::new(&Vector3::from(*theta_r)).c * self.chart_rotation())),
        }
    }

    /// Earth rate in the chart frame r, rad/s: `R·w_e0`.
    #[inline] // cold set-up: compiled in its (opt-level "z") caller in the firmware, issue 10
    pub fn earth_rate_r(&self) -> Vector3<f64> {
        match self.chart {
            Chart::Enu => self.earth_rate_0(),
            _ => self.chart_rotation() * self.earth_rate_0(),
        }
    }

    /// Specific force at rest in the chart frame r, m/s²: `R·[0, 0, g]`.
    pub fn gravity_r(&self) -> Vector3<f64> {
        match self.chart {
            Chart::Enu => self.gravity_0(),
            _ => self.chart_rotation() * self.gravity_0(),
        }
    }

    /// Local north in the chart frame r (unit): `R·[0, 1, 0]`.
    #[inline] // cold set-up: compiled in its (opt-level "z") caller in the firmware, issue 10
    pub fn north_r(&self) -> Vector3<f64> {
        match self.chart {
            Chart::Enu => Vector3::new(0.0, 1.0, 0.0),
            _ => self.chart_rotation() * Vector3::new(0.0, 1.0, 0.0),
        }
    }

    /// Earth rate in frame 0 (ENU), rad/s: `[0, Ω cos L, Ω sin L]`.
    pub fn earth_rate_0(&self) -> Vector3<f64> {
        let (s, c) = crate::trig::sincos(self.latitude_rad);
        Vector3::new(0.0, EARTH_RATE_RADPS * c, EARTH_RATE_RADPS * s)
    }

    /// Specific force at rest in frame 0, m/s²: `[0, 0, +g]`.
    pub fn gravity_0(&self) -> Vector3<f64> {
        Vector3::new(0.0, 0.0, self.gravity_mps2)
    }
}

/// WGS-84 normal gravity on the ellipsoid (Somigliana), m/s². 9.800898 m/s² at 39.1° N.
pub fn normal_gravity(latitude_rad: f64) -> f64 {
    // The crate's one sine (trig.rs): no libm `sin` in the firmware image (issue 10).
    let s = crate::trig::sincos(latitude_rad).0;
    let s2 = s * s;
    9.780_325_335_9 * (1.0 + 0.001_931_852_652_41 * s2)
        / sampling::sqrt(1.0 - 0.006_694_379_990_13 * s2)
}

/// Euler angles (rad) of a rotation matrix `C = Rz(tz)·Ry(ty)·Rx(tx)` (passive): ty in
/// [−90°, 90°], tx and tz in (−180°, 180°]. Row 2 of C is (sy, −sx·cy, cx·cy), column 0 is
/// (cy·cz, −cy·sz, sy).
pub fn euler_zyx(c: &Matrix3<f64>) -> [f64; 3] {
    let ty = libm::asin(c[(2, 0)].clamp(-1.0, 1.0));
    let tx = libm::atan2(-c[(2, 1)], c[(2, 2)]);
    let tz = libm::atan2(-c[(1, 0)], c[(0, 0)]);
    [tx, ty, tz]
}

/// The platform attitude C_r^p at θ, with the sines and cosines of θ (its partial derivatives
/// ∂C/∂θ_j on demand: [`Attitude::dc`]; the filter's Jacobians take cheaper routes).
#[derive(Clone, Copy, Debug)]
pub struct Attitude {
    /// C_0^p: frame-0 vectors to platform axes.
    pub c: Matrix3<f64>,
    /// sin and cos of (tx, ty, tz).
    pub sin: Vector3<f64>,
    /// cos of (tx, ty, tz).
    pub cos: Vector3<f64>,
}

impl Attitude {
    /// Attitude at Euler angles θ = (tx, ty, tz), rad.
    pub fn new(theta: &Vector3<f64>) -> Self {
        let (sx, cx) = crate::trig::sincos(theta.x);
        let (sy, cy) = crate::trig::sincos(theta.y);
        let (sz, cz) = crate::trig::sincos(theta.z);
        // C = Rz·Ry·Rx multiplied out (Rx = [[1,0,0],[0,c,s],[0,-s,c]], …).
        let (sxsy, cxsy) = (sx * sy, cx * sy);
        let row0 = Vector3::new(cy * cz, cx * sz + sxsy * cz, sx * sz - cxsy * cz);
        let row1 = Vector3::new(-cy * sz, cx * cz - sxsy * sz, sx * cz + cxsy * sz);
        let row2 = Vector3::new(sy, -sx * cy, cx * cy);
        let c = Matrix3::from_rows(&[row0.transpose(), row1.transpose(), row2.transpose()]);
        Attitude {
            c,
            sin: Vector3::new(sx, sy, sz),
            cos: Vector3::new(cx, cy, cz),
        }
    }

    /// ∂C/∂tx, ∂C/∂ty, ∂C/∂tz (C multiplied out, differentiated term by term).
    pub fn dc(&self) -> [Matrix3<f64>; 3] {
        let (sx, sy, sz) = (self.sin.x, self.sin.y, self.sin.z);
        let (cx, cy, cz) = (self.cos.x, self.cos.y, self.cos.z);
        let (sxsy, cxsy) = (sx * sy, cx * sy);
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
            self.c.row(1).into_owned(),
            -self.c.row(0),
            Vector3::zeros().transpose(),
        ]);
        [d_tx, d_ty, d_tz]
    }

    /// Specific force along the platform axes when the base is at rest, `A = C·g_r`, m/s²
    /// (`g_r`: gravity in the chart frame, [`Site::gravity_r`]).
    pub fn specific_force(&self, g_r: &Vector3<f64>) -> Vector3<f64> {
        self.c * g_r
    }

    /// ∂A/∂θ_j, m/s² per rad.
    pub fn d_specific_force(&self, g_r: &Vector3<f64>, j: usize) -> Vector3<f64> {
        self.dc()[j] * g_r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run described in the polar chart predicts the same specific force and, after
    /// integration, the same ENU attitude as in the ENU chart (the charts are one physics).
    #[test]
    fn charts_agree_on_the_physics() {
        let mut polar = Site::new(39.1, None);
        polar.chart = Chart::Polar;
        let enu = Site::new(39.1, None);
        let theta_enu = [0.3, -0.2, 0.7];
        let theta_r = polar.angles_to_chart(&theta_enu);
        // Round trip to rounding (1e-15 rad).
        let back = polar.angles_to_enu(&theta_r);
        for i in 0..3 {
            assert!((back[i] - theta_enu[i]).abs() < 1e-14, "{back:?}");
        }
        let a_enu = Attitude::new(&Vector3::from(theta_enu)).specific_force(&enu.gravity_r());
        let a_r = Attitude::new(&Vector3::from(theta_r)).specific_force(&polar.gravity_r());
        assert!((a_enu - a_r).norm() < 1e-13, "{a_enu} vs {a_r}");
        // Earth rate along the platform axes is frame-independent too.
        let w_enu = Attitude::new(&Vector3::from(theta_enu)).c * enu.earth_rate_r();
        let w_r = Attitude::new(&Vector3::from(theta_r)).c * polar.earth_rate_r();
        assert!((w_enu - w_r).norm() < 1e-19, "{w_enu} vs {w_r}");
        // R is a proper rotation.
        let r = polar.chart_rotation();
        assert!((r * r.transpose() - Matrix3::identity()).norm() < 1e-15);
        assert!((r.determinant() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn euler_extraction_inverts_attitude() {
        for theta in [[0.1, 0.2, 0.3], [-2.5, 1.2, 3.0], [3.0, -1.5, -0.1]] {
            let got = euler_zyx(&Attitude::new(&Vector3::from(theta)).c);
            for i in 0..3 {
                assert!((got[i] - theta[i]).abs() < 1e-12, "{theta:?} -> {got:?}");
            }
        }
    }
}
