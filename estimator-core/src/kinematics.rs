//! Platform kinematics (paper eqs. 3–4): the Euler-angle rate θ̇ produced by a platform rate
//! `w = w_d − C·w_e0` (rad/s, platform axes), and its derivative with respect to θ at fixed `w`.
//!
//! `w = M(θ)·θ̇`, `M = [[cy·cz, sz, 0], [−cy·sz, cz, 0], [sy, 0, 1]]`, so `θ̇ = K(θ)·w` with K = M⁻¹.
//! Singular at ty = ±90°, which rotation about the polar axis reaches only at the equator.

use nalgebra::{Matrix3, Vector3};

use crate::frames::Attitude;

/// K(θ) = M(θ)⁻¹: maps a platform angular rate (rad/s) to Euler-angle rates (rad/s).
pub fn rate_to_euler(att: &Attitude) -> Matrix3<f64> {
    rate_to_euler_yz((att.sin.y, att.cos.y), (att.sin.z, att.cos.z))
}

/// [`rate_to_euler`] from (sin, cos) of ty and of tz, which are all K depends on.
pub fn rate_to_euler_yz((sy, cy): (f64, f64), (sz, cz): (f64, f64)) -> Matrix3<f64> {
    let inv_cy = 1.0 / cy; // one division, not three
    let ty = sy * inv_cy;
    Matrix3::new(
        cz * inv_cy,
        -sz * inv_cy,
        0.0,
        sz,
        cz,
        0.0,
        -ty * cz,
        ty * sz,
        1.0,
    )
}

/// ∂(K(θ)·w)/∂θ_j at fixed `w`, as the three columns j = x, y, z.
pub fn d_rate_to_euler(att: &Attitude, w: &Vector3<f64>) -> [Vector3<f64>; 3] {
    let (sy, cy) = (att.sin.y, att.cos.y);
    let (sz, cz) = (att.sin.z, att.cos.z);
    let a = cz * w.x - sz * w.y;
    let b = sz * w.x + cz * w.y;
    let inv_cy = 1.0 / cy; // one division, not four
    let a_cy2 = a * inv_cy * inv_cy;
    [
        Vector3::zeros(),
        Vector3::new(a_cy2 * sy, 0.0, -a_cy2),
        Vector3::new(-b * inv_cy, a, sy * inv_cy * b),
    ]
}
