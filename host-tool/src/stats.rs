//! Statistics helpers: χ² quantiles and tail probabilities and normal quantiles, all from statrs
//! (exact: regularised incomplete gamma and its inversion, inverse complementary error function).
//!
//! One formula is our own, where statrs cannot answer: the log of a χ² tail beyond f64 underflow
//! ([`chi2_ln_sf`]; statrs has no log-survival function and its `sf` is 0 there). The noncentral
//! χ² of the detection limits is approximated in [`crate::diagnose::candidates`] (statrs has
//! none).

/// Standard normal quantile (statrs: `√2·erfc⁻¹(2(1−p))`, exact to rounding).
pub(crate) fn normal_quantile(p: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, Normal};
    match Normal::new(0.0, 1.0) {
        Ok(d) if (0.0..=1.0).contains(&p) => d.inverse_cdf(p),
        _ => f64::NAN,
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
pub(crate) fn chi2_sf(x: f64, k: f64) -> f64 {
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
/// Where the tail is representable it is statrs' `sf` (exact); beyond (p < 1e-300: statrs'
/// `gamma_ur` returns 0 once its prefactor e^(a ln x − x − lnΓ(a)) underflows) the Legendre
/// continued fraction of Q(a, x) — the fraction statrs itself evaluates for x > a, Cephes'
/// `igamc` — is evaluated with its prefactor kept in logs:
/// `ln Q = −x + a·ln x − lnΓ(a) + ln CF(a, x)`, a = k/2, x = stat/2 (lnΓ from statrs). It is
/// exact to rounding too, not an asymptotic approximation: the fraction converges fastest
/// exactly there (x ≫ a). Tested against scipy's `logsf` where both are finite and against the
/// leading terms of the asymptotic series beyond.
pub(crate) fn chi2_ln_sf(x: f64, k: f64) -> f64 {
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
        // scipy.stats.norm.ppf: 2.5758293035489004 and -6.361340902404056 (far tail).
        assert!((normal_quantile(0.995) - 2.575_829_303_548_900_4).abs() < 1e-12);
        assert!((normal_quantile(1e-10) + 6.361_340_902_404_056).abs() < 1e-10);
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
