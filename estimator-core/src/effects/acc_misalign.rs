//! Accelerometer input-axis misalignment / non-orthogonality: `z_i += Σ_{j≠i} m_ij·A_j` (rad).

use nalgebra::Vector3;

use super::{Context, Effect, Param, Partials};

/// Misalignment, six small angles in rad: xy, xz, yx, yz, zx, zy (accelerometer i sensing axis j).
#[derive(Clone, Copy, Debug, Default)]
pub struct AccMisalign;

const M: f64 = 1e-3; // rad (~200 arcsec)
const PARAMS: [Param; 6] = [
    Param {
        name: "Mxy",
        unit: "rad",
        prior_sigma: M,
    },
    Param {
        name: "Mxz",
        unit: "rad",
        prior_sigma: M,
    },
    Param {
        name: "Myx",
        unit: "rad",
        prior_sigma: M,
    },
    Param {
        name: "Myz",
        unit: "rad",
        prior_sigma: M,
    },
    Param {
        name: "Mzx",
        unit: "rad",
        prior_sigma: M,
    },
    Param {
        name: "Mzy",
        unit: "rad",
        prior_sigma: M,
    },
];
/// (sensing accelerometer i, axis j) of each parameter.
pub const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)];

impl Effect for AccMisalign {
    fn name(&self) -> &'static str {
        "acc-misalign"
    }
    fn about(&self) -> &'static str {
        "Accelerometer misalignment and non-orthogonality: each accelerometer's input axis leans \
         towards the other platform axes by small angles, so it picks up a fraction of their \
         specific force. With z carrying nearly g, the x and y accelerometers see it as an offset \
         that follows the gravity cone; nearly confounded with bias and scale factor on one run."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    fn accel_error(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let a = &ctx.specific_force;
        for (k, &(i, j)) in PAIRS.iter().enumerate() {
            out.value[i] += p[k] * a[j];
            out.d_params[k] = Vector3::ith(i, a[j]);
            out.d_force[(i, j)] += p[k];
        }
    }
    fn touches_drift(&self) -> bool {
        false
    }
    fn touches_accel(&self) -> bool {
        true
    }
}
