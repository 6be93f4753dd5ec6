//! Unit conversions and physical constants. Internal angles are radians and times seconds;
//! drift coefficients are kept in the user's units (deg/h, deg/h/(m/s²)) inside the state so the
//! covariance is well scaled, and converted to rad/s only where the kinematics need it.

/// Radians per degree.
pub const RAD_PER_DEG: f64 = core::f64::consts::PI / 180.0;
/// rad/s per deg/h.
pub const RADPS_PER_DEGPH: f64 = RAD_PER_DEG / 3600.0;
/// Earth rotation rate, rad/s (WGS-84).
pub const EARTH_RATE_RADPS: f64 = 7.292_115e-5;
/// Seconds per hour.
pub const S_PER_H: f64 = 3600.0;
/// Radians per arcsecond.
pub const RAD_PER_ARCSEC: f64 = RAD_PER_DEG / 3600.0;

/// Converts an angle-random-walk variance density in deg²/h (the paper's "Var(eps) = 1e-8 deg²/h")
/// to the rate-noise spectral density in rad²/s used by the filter.
pub fn arw_deg2ph_to_rad2ps(var_deg2_per_h: f64) -> f64 {
    var_deg2_per_h * RAD_PER_DEG * RAD_PER_DEG / S_PER_H
}
