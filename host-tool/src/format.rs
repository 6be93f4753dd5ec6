//! Number formatting: a value printed to the precision its 1σ supports, one rule everywhere
//! ([`decimals_for`]: two significant digits of 1σ, the value to the same decimal). [`pm`] prints
//! `value ± 1σ` (text, HTML and the plots' annotations); [`with_sigma`] prints the value alone
//! for tables whose 1σ has its own column.

/// Decimals needed to show two significant digits of `sigma`.
pub(crate) fn decimals_for(sigma: f64) -> usize {
    if !(sigma.is_finite() && sigma > 0.0) {
        return 6;
    }
    (1.0 - sigma.log10().floor()).clamp(0.0, 12.0) as usize
}

/// `value` with the decimals that two significant digits of `sigma` need; in scientific
/// notation, as [`pm`] writes it, when the numbers are very small or large (`2.942e-6`, not
/// `0.000002942`).
pub(crate) fn with_sigma(value: f64, sigma: f64) -> String {
    match sci_digits(value, sigma) {
        Some(d) => format!("{value:.d$e}"),
        None => format!("{:.*}", decimals_for(sigma), value),
    }
}

/// The mantissa decimals of `value` in scientific notation when `value ± sigma` is too small or
/// large for fixed decimals (the rule of [`pm`]); `None`: fixed decimals.
fn sci_digits(value: f64, sigma: f64) -> Option<usize> {
    if !(value.is_finite() && sigma.is_finite() && sigma > 0.0) {
        return None;
    }
    let last = sigma.log10().floor() as i32 - 1; // place of sigma's second significant digit
    let mag = if value != 0.0 {
        value.abs().log10().floor() as i32
    } else {
        last + 1
    };
    if (-3..5).contains(&mag.max(last + 1)) && last >= -12 {
        None
    } else {
        Some((mag.max(last + 1) - last).clamp(1, 15) as usize)
    }
}

/// `v` to `digits` significant digits, without trailing zeros (`0.4903942405116055` → `0.4903942`).
pub(crate) fn sig(v: f64, digits: usize) -> String {
    if !v.is_finite() || v == 0.0 {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor() as i32;
    if (-4..7).contains(&mag) {
        let d = (digits as i32 - 1 - mag).clamp(0, 15) as usize;
        let s = format!("{v:.d$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        // Trailing zeros of the mantissa trimmed as above: a truth of 4e-5 is "4e-5", not
        // "4.000000e-5" (the digits are the value's, not a precision).
        let s = format!("{v:.*e}", digits.saturating_sub(1));
        match s.split_once('e') {
            Some((m, e)) if m.contains('.') => {
                format!("{}e{e}", m.trim_end_matches('0').trim_end_matches('.'))
            }
            _ => s,
        }
    }
}

/// A number in short scientific notation, e.g. `3.1e-4`.
pub(crate) fn sci(v: f64) -> String {
    format!("{v:.2e}")
}

/// `value ± sigma` with two significant digits of `sigma` and the value to the same decimal, in
/// scientific notation when the numbers are very small or large: `2.00031e-3 ± 9.0e-7`,
/// `0.0921 ± 0.0065`. A missing or zero 1σ prints the value alone with 4 significant digits.
pub fn pm(value: f64, sigma: f64) -> String {
    if !value.is_finite() {
        return "n/a".into();
    }
    if !(sigma.is_finite() && sigma > 0.0) {
        return format!("{value:.3e}");
    }
    match sci_digits(value, sigma) {
        None => {
            let d = decimals_for(sigma);
            format!("{value:.d$} ± {sigma:.d$}")
        }
        Some(d) => format!("{value:.d$e} ± {sigma:.1e}"),
    }
}

/// A p-value, the one way every command and the page print it: two decimals in scientific
/// notation (`4.21e-1`), also below the smallest double, from its natural log `ln_p` when given
/// (`3.72e-2083`); `< 1e-308` when it underflowed without one, `n/a` when undefined.
pub(crate) fn p_value(p: f64, ln_p: f64) -> String {
    if p.is_nan() {
        "n/a".into()
    } else if p > 0.0 || (p == 0.0 && ln_p == f64::NEG_INFINITY) {
        format!("{p:.2e}")
    } else if ln_p.is_finite() {
        let log10 = ln_p / std::f64::consts::LN_10;
        let e = log10.floor();
        let m = 10f64.powf(log10 - e);
        // 9.995… rounds to 10.00: carry into the exponent.
        let (m, e) = if m >= 9.995 { (1.0, e + 1.0) } else { (m, e) };
        format!("{m:.2}e{e}")
    } else {
        "< 1e-308".into()
    }
}

#[cfg(test)]
mod pm_tests {
    use super::pm;

    #[test]
    fn digits_follow_the_sigma() {
        assert_eq!(pm(-0.0921, 6.49e-6), "-0.0921000 ± 0.0000065");
        assert_eq!(pm(2.0003e-3, 9.04e-7), "0.00200030 ± 0.00000090");
        assert_eq!(pm(5.54e-6, 2.07e-7), "5.54e-6 ± 2.1e-7");
        assert_eq!(pm(12345.6, 78.0), "12346 ± 78");
    }

    #[test]
    fn a_value_alone_follows_the_same_rule() {
        use super::with_sigma;
        // The paper's coefficients keep their fixed decimals; a tiny one reads as 2.942e-6.
        assert_eq!(with_sigma(-0.099995, 9.08e-5), "-0.099995");
        assert_eq!(with_sigma(2.942e-6, 6.79e-8), "2.942e-6");
        assert_eq!(with_sigma(-8.8e-4, 5.68e-4), "-8.8e-4");
    }
}

#[cfg(test)]
mod sig_tests {
    use super::sig;

    /// A value written with a number of significant digits (the truth column) keeps only the
    /// digits it has, in fixed and in scientific notation alike.
    #[test]
    fn a_values_own_digits_and_no_more() {
        assert_eq!(sig(4e-5, 7), "4e-5");
        assert_eq!(sig(-1.23456e-5, 7), "-1.23456e-5");
        assert_eq!(sig(1.2345678e-5, 7), "1.234568e-5");
        assert_eq!(sig(0.05, 7), "0.05");
        assert_eq!(sig(1.5e9, 7), "1.5e9");
    }
}

#[cfg(test)]
mod p_value_tests {
    use super::p_value;

    #[test]
    fn one_style_above_and_below_the_smallest_double() {
        assert_eq!(p_value(0.4213, f64::NAN), "4.21e-1");
        assert_eq!(p_value(0.0, -4.8e6), "3.07e-2084614");
        assert_eq!(p_value(0.0, f64::NAN), "< 1e-308");
        assert_eq!(p_value(f64::NAN, f64::NAN), "n/a");
        // ln p of 1e-400 exactly: 1.00e-400, not 10.00e-401.
        assert_eq!(p_value(0.0, -400.0 * std::f64::consts::LN_10), "1.00e-400");
    }
}
