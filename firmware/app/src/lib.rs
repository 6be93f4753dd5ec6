//! # firmware-app — the navigation computer's application, board-independent
//!
//! Builds for the target (`thumbv7em-none-eabihf`, used by the `firmware` crate's boards) and for
//! the host, where its drivers and loop are tested with `embedded-hal-mock` and an in-memory link.
//!
//! - [`accel`]: the [`accel::Accelerometer`] trait (specific force in m/s² with a sample time).
//! - [`adxl355`]: the ADXL355 driver over `embedded_hal::spi::SpiDevice`.
//! - [`app`]: the loop: commands and replayed samples from the link, sampling at a fixed rate,
//!   rejection and counting of invalid samples, averaging, the real-time EKF, telemetry,
//!   checkpoints and resume after a reset.
//! - [`cmsdk_uart`]: the CMSDK APB UART of the QEMU board (its bring-up and receive
//!   interrupt), testable on the host against a model of QEMU's UART.
//! - [`checkpoints`]: the append-only checkpoint log over NOR flash (few erases, power-loss safe).
//! - [`resume`]: the resume block (one documented layout) stored with the filter image.
//! - [`screen`]: sample screening: the firmware's arrival checks (NaN/∞, saturation, time
//!   order), then estimator-core's streaming screener (dropouts, stuck axes, glitches).
//! - [`counters`]: what the application counts, incremented in one place.
//! - [`serial`]: the receive ring the UART interrupt fills, so no byte is lost while the loop
//!   is blocked (flash erase, filter step).
#![no_std]
#![warn(missing_docs)]

pub mod accel;
pub mod adxl355;
pub mod app;
pub mod checkpoints;
pub mod cmsdk_uart;
pub mod counters;
pub mod resume;
pub mod screen;
pub mod serial;

pub use accel::{AccelSample, Accelerometer, NoSensor};
pub use app::{App, Event, NoTimer, Platform, SampleTimer, Tick};
