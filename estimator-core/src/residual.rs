//! The residual record every measurement update returns: what the diagnosis is built on.

/// One measurement update seen from outside: measured vs predicted, innovation and its
/// covariance, the whitened innovation and the normalised innovation squared.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Residual {
    /// Update number (0-based).
    pub step: u32,
    /// Time tag of the measurement (mean sample time of its averaging window), s.
    pub t_s: f64,
    /// Measured specific force (window mean), m/s², platform axes.
    pub measured: [f64; 3],
    /// Predicted specific force h(x⁻), m/s².
    pub predicted: [f64; 3],
    /// Innovation ν = measured − predicted, m/s².
    pub innovation: [f64; 3],
    /// Innovation covariance S = H P⁻ Hᵀ + R, (m/s²)², row-major.
    pub s: [[f64; 3]; 3],
    /// Whitened innovation L⁻¹ν with S = L Lᵀ: unit-variance white noise when the model holds.
    pub whitened: [f64; 3],
    /// Normalised innovation squared νᵀ S⁻¹ ν: χ²(3) when the model holds.
    pub nis: f64,
    /// The update was refused by the innovation gate (NIS above it): state not corrected.
    pub rejected: bool,
}
