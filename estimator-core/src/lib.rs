//! # estimator-core
//!
//! The estimator of a space-stable INS's gyro drift coefficients from its accelerometers: the
//! platform model, the physical effects, the averaging of raw samples and the extended Kalman
//! filter. `no_std`, no heap, `f64`, nalgebra with `libm`; the firmware and the host tool run this
//! same code. `std`/`alloc` are opt-in features for the host.
//!
//! ## Why a fixed capacity with a run-time dimension
//! The state grows by blocks as physical effects are added (g²-sensitive drift, accelerometer
//! errors, drift trend, …). On the host the user picks the effects at run time; on the navigation
//! computer there is no heap. We keep one filter, [`filter::Ekf`]`<CAP>`, whose arrays have a
//! compile-time capacity `CAP` and whose active dimension is the model's (`≤ CAP`), with the
//! effects chosen as a slice of `&dyn` [`effects::Effect`] (no allocation). The alternative,
//! nalgebra generic dimensions (`Const<N>` on target, `Dyn` on the host), would need
//! allocation on the host and monomorphised copies per model on the target. With a
//! capacity the firmware sizes `CAP` to its model (15 for the paper's: no wasted flops or RAM),
//! the host uses [`model::MAX_STATES`], and the structured step (Φ ≠ I only in the dynamic rows,
//! H ≠ 0 only in the measured columns) does the work of the active block only.
//!
//! ## One filter step
//! The paper's model at 39.1° N (3 platform angles, 12 drift coefficients), started as the
//! paper starts it (angles and coefficients 0; the coefficients' prior 1σ 1 deg/h for D0, 0.2
//! deg/h/(m/s²) for the g-sensitive terms), takes one 60-s mean of the accelerometers. Here the
//! mean is exactly what the filter predicts, so the innovation and the NIS are 0 and the
//! estimate does not move; the filter still learns: the 1σ of the coefficients shrink.
//!
//! ```
//! use estimator_core::units::arw_deg2ph_to_rad2ps;
//! use estimator_core::{step_paper, Ekf, Measurement, Model, Propagation, Site, PAPER_EFFECTS};
//!
//! let site = Site::new(39.1, None); // latitude, deg; normal gravity when None
//! let arw = arw_deg2ph_to_rad2ps(1e-8); // gyro rate noise, deg²/h → rad²/s
//! let model = Model::new(site, &PAPER_EFFECTS, arw, Propagation::default()).unwrap();
//! let mut ekf: Ekf<'_, 15> = Ekf::with_default_prior(model).unwrap();
//! let prior: Vec<f64> = (0..15).map(|i| ekf.sigma(i)).collect();
//!
//! let mut mean = Measurement {
//!     t_s: 60.0,                     // mean sample time, s
//!     specific_force: [0.0; 3],      // m/s², platform axes (set below)
//!     temp_c: f64::NAN,              // not measured
//!     count: 60,                     // samples averaged
//!     variance: [1e-8; 3],           // variance of the mean, (m/s²)²: 1σ 1e-4 m/s²
//!     time_var_s2: 0.0,              // spread of the sample times, s²
//! };
//! // What the filter expects to read (gravity, turned by the Earth's rotation in 60 s).
//! mean.specific_force = step_paper(&mut ekf.clone(), &mean).unwrap().predicted;
//! let g = ekf.model().site().gravity_mps2;
//! assert!((mean.specific_force[2] - g).abs() < 1e-3 * g);
//!
//! let r = step_paper(&mut ekf, &mean).unwrap();
//! assert_eq!((ekf.steps(), ekf.time_s()), (1, 60.0));
//! assert_eq!((r.innovation, r.nis), ([0.0; 3], 0.0));
//! // DX0 (state 3): one minute narrows its 1σ by ~11 % (< 0.95: deterministic, with a margin);
//! // no coefficient's 1σ grows.
//! assert!(ekf.sigma(3) < 0.95 * prior[3], "{} of {}", ekf.sigma(3), prior[3]);
//! assert!((3..15).all(|i| ekf.sigma(i) <= prior[i]));
//! ```
//!
//! ## Modules
//! - [`units`]: constants and conversions (deg/h ↔ rad/s, ARW).
//! - [`frames`]: frame 0 (ENU), C_0^p(θ) and its derivatives, the site and normal gravity.
//! - [`kinematics`]: θ̇ from the platform rate (paper eq. 4).
//! - [`effects`]: the [`effects::Effect`] trait and the catalog (the paper's drift model first).
//! - [`model`]: state layout, f/F and h/H.
//! - [`propagate`]: RK4 (default) or the paper's Euler step for the state and Φ.
//! - [`filter`]: the EKF with Joseph-form update, returning a [`residual::Residual`] per update.
//! - [`averaging`]: raw samples → filter-period means tagged at the mean sample time.
//! - [`screening`]: raw-sample screening (glitches, stuck/dead channels, non-finite) before averaging.
//! - [`checkpoint`]: the filter's complete state as a versioned, CRC-checked image (resets).
//! - [`cpu`]: whether the CPU has AVX2, for the hot loops' builds that use it (x86-64).
#![no_std]
#![warn(missing_docs)]

#[cfg(feature = "alloc")]
extern crate alloc;
#[cfg(feature = "std")]
extern crate std;

pub mod checkpoint;
pub mod cpu;
pub mod effects;
pub mod filter;
pub mod frames;
pub mod kinematics;
pub mod model;
pub mod propagate;
pub mod residual;
pub mod trig;
pub mod units;

// Screening and averaging of raw samples live in the `sampling` crate (the firmware optimises
// them for size, the EKF here for speed); re-exported under their former paths, with the one
// median (`robust`) the screening and the host share.
pub use sampling::{averaging, robust, screening};

pub use averaging::{Averager, Measurement, Sample};
pub use effects::{Effect, PaperDrift};
pub use filter::{Ekf, FilterError};
pub use frames::Site;
pub use model::{Model, Propagation};
pub use residual::Residual;

/// The paper's model as a ready-made effect list: the 12 drift coefficients.
pub static PAPER_EFFECTS: [&dyn Effect; 1] = [&PaperDrift];

/// States of the paper's model: 3 angles and the 12 drift coefficients of [`PAPER_EFFECTS`].
pub const PAPER_STATES: usize = 15;

/// One update of a filter of the paper's model ([`Ekf::step`] for [`PAPER_STATES`] states),
/// instantiated and optimised in this crate: the firmware, which optimises its own code for
/// size, calls this so that the EKF update keeps this crate's optimisation level.
#[inline(never)]
pub fn step_paper(
    ekf: &mut Ekf<'_, PAPER_STATES>,
    m: &Measurement,
) -> Result<Residual, FilterError> {
    ekf.step(m)
}
