//! Accelerometer abstraction: what the application needs from a sensor.

/// One accelerometer reading, tagged with its sample time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AccelSample {
    /// Sample time, s since the gyros reached stable operation (from the board's sample timer).
    pub t_s: f64,
    /// Specific force along the platform axes x_p, y_p, z_p, m/s².
    pub specific_force: [f64; 3],
    /// Sensor temperature, °C (NaN when not measured).
    pub temp_c: f64,
    /// The sensor reported an axis at the end of its range: the value is clipped, not a measurement.
    pub saturated: bool,
}

/// A 3-axis accelerometer aligned with the platform axes.
pub trait Accelerometer {
    /// Read errors (bus errors, data not ready).
    type Error: core::fmt::Debug;

    /// Reads the latest sample and tags it with `t_s`.
    fn sample(&mut self, t_s: f64) -> Result<AccelSample, Self::Error>;

    /// Whether a sensor is fitted at all (QEMU has none: samples come by replay only).
    fn present(&self) -> bool {
        true
    }
}

/// The accelerometer of a board that has none (QEMU): every read fails.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoSensor;

/// The error of [`NoSensor`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NotFitted;

impl Accelerometer for NoSensor {
    type Error = NotFitted;
    fn sample(&mut self, _t_s: f64) -> Result<AccelSample, NotFitted> {
        Err(NotFitted)
    }
    fn present(&self) -> bool {
        false
    }
}
