//! # sampling
//!
//! What happens to raw accelerometer samples before the EKF, shared by firmware and host:
//! - [`screening`]: raw-sample screening (glitches, stuck/dead channels, non-finite) before averaging.
//! - [`averaging`]: raw samples → filter-period means tagged at the mean sample time.
//!
//! A crate of its own, apart from the EKF in `estimator-core` (which re-exports both modules
//! under the same paths), so that the firmware can optimise it for size while the EKF keeps
//! its speed (Cargo.toml, `[profile.firmware]`). `no_std`, no heap.
#![no_std]
#![warn(missing_docs)]

pub mod averaging;
pub mod screening;

pub use averaging::{Averager, Measurement, Sample};
