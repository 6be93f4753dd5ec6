//! Statistics helpers: χ² quantiles and tail probabilities (statrs), the log tail beyond
//! underflow, normal quantiles.

/// Standard normal quantile (Acklam's rational approximation, |error| < 1.2e-9).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let pl = 0.02425;
    if p < pl {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - pl {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        -normal_quantile(1.0 - p)
    }
}

/// χ² quantile with `k` degrees of freedom (statrs: exact inversion of the regularised gamma).
pub fn chi2_quantile(p: f64, k: f64) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    match ChiSquared::new(k) {
        Ok(d) if (0.0..=1.0).contains(&p) => d.inverse_cdf(p),
        _ => f64::NAN,
    }
}

/// Upper tail probability of χ²(k) at `x`: the p-value of a χ² statistic (statrs).
pub fn chi2_sf(x: f64, k: f64) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    match ChiSquared::new(k) {
        Ok(d) if x.is_finite() => d.sf(x.max(0.0)).clamp(0.0, 1.0),
        Ok(_) if x == f64::INFINITY => 0.0,
        _ => f64::NAN,
    }
}

/// Natural log of the χ²(k) upper tail at `x`: a p-value that does not underflow, so statistics
/// of 1e6 on 3 and on 33 degrees of freedom still rank by evidence, not by a tie at 0.
///
/// Where the tail is representable it is statrs' `sf`; beyond (p < 1e-300) the Legendre
/// continued fraction of Q(a, x) is evaluated in log form:
/// `ln Q = −x + a·ln x − lnΓ(a) + ln CF(a, x)`, a = k/2, x = stat/2.
pub fn chi2_ln_sf(x: f64, k: f64) -> f64 {
    let p = chi2_sf(x, k);
    if p > 1e-300 {
        return p.ln();
    }
    let (a, x) = (0.5 * k, 0.5 * x);
    -x + a * x.ln() - statrs::function::gamma::ln_gamma(a) + gamma_q_cf(a, x).ln()
}

/// The continued fraction of Q(a, x)·e^x·x^(−a)·Γ(a) for x > a + 1 (modified Lentz).
fn gamma_q_cf(a: f64, x: f64) -> f64 {
    let mut b = x + 1.0 - a;
    let mut c = 1.0 / 1e-300;
    let mut d = 1.0 / b;
    let mut h = d;
    for i in 1..10_000 {
        let an = -(i as f64) * (i as f64 - a);
        b += 2.0;
        d = an * d + b;
        if d.abs() < 1e-300 {
            d = 1e-300;
        }
        c = b + an / c;
        if c.abs() < 1e-300 {
            c = 1e-300;
        }
        d = 1.0 / d;
        let del = d * c;
        h *= del;
        if (del - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_tables() {
        // Reference values from standard χ² tables (4 significant digits).
        assert!((chi2_quantile(0.975, 12.0) - 23.34).abs() < 0.05);
        assert!((chi2_quantile(0.025, 12.0) - 4.404).abs() < 0.05);
        assert!((chi2_sf(23.34, 12.0) - 0.025).abs() < 2e-4);
        assert!((chi2_sf(7.815, 3.0) - 0.05).abs() < 2e-4);
        assert!((normal_quantile(0.975) - 1.959964).abs() < 1e-6);
    }

    #[test]
    fn log_tail_continues_where_the_tail_underflows() {
        // Where the tail is representable: scipy.stats.chi2.logsf(1000, 3) = -496.77091520884.
        assert!((chi2_ln_sf(1000.0, 3.0) - (-496.770_915_208_84)).abs() < 1e-6);
        // Past underflow (scipy's logsf returns -inf): ln Q(1.5, 1000) by the asymptotic series
        // −x + (a−1)·ln x − lnΓ(a) + ln(1 + (a−1)/x) = −996.42; and at 9.6e6 the log tail stays
        // finite and ordered — more dof at the same statistic is less significant.
        let l3 = chi2_ln_sf(9.6e6, 3.0);
        let l33 = chi2_ln_sf(9.6e6, 33.0);
        assert!(l3.is_finite() && l33.is_finite());
        assert!(l3 < l33, "{l3} {l33}");
        assert!((chi2_ln_sf(2000.0, 3.0) - (-996.42)).abs() < 0.01);
    }
}
