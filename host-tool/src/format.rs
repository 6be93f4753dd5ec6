//! Number formatting for tables: a value printed to the precision its 1σ supports.

/// Decimals needed to show two significant digits of `sigma`.
pub fn decimals_for(sigma: f64) -> usize {
    if !(sigma.is_finite() && sigma > 0.0) {
        return 6;
    }
    (1.0 - sigma.log10().floor()).clamp(0.0, 12.0) as usize
}

/// `value` with the decimals that two significant digits of `sigma` need.
pub fn with_sigma(value: f64, sigma: f64) -> String {
    format!("{:.*}", decimals_for(sigma), value)
}

/// A number in short scientific notation, e.g. `3.1e-4`.
pub fn sci(v: f64) -> String {
    format!("{v:.2e}")
}
