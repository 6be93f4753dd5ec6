//! Robust location and scale: the median and the 1σ it gives, one definition for the
//! screening (firmware and host) and every statistic of the host that ignores outliers.
//!
//! The median of an even count is the mean of the middle pair (the screening's definition, which
//! the firmware's estimates are compared with bit for bit). Two ways to find it, one value:
//! [`median`] selects in linear time (the host's long series), [`median_of_few`] sorts in place
//! (the screening's windows of at most 15 values: no selection code in the firmware image).

use core::cmp::Ordering;

/// The median of |x| of a zero-mean normal variable times this is its σ (1/Φ⁻¹(3/4)).
pub const NORMAL_SIGMA_PER_MEDIAN_ABS: f64 = 1.4826;

/// The median of `v` (reordered in place): the middle value, or the mean of the middle pair
/// for an even count; NaN for none. Linear time.
pub fn median(v: &mut [f64]) -> f64 {
    median_by(v, f64::total_cmp, |x| x)
}

/// [`median`] of values that order by `cmp` and read as `value` (e.g. sample counts, or the
/// bits of non-negative floats, whose integer order is their numeric order and selects faster).
pub fn median_by<T: Copy>(
    v: &mut [T],
    cmp: impl Fn(&T, &T) -> Ordering,
    value: impl Fn(T) -> f64,
) -> f64 {
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    let (lower, upper, _) = v.select_nth_unstable_by(n / 2, &cmp);
    let upper = value(*upper);
    if n % 2 == 1 {
        return upper;
    }
    // The lower of the middle pair is the largest of the values the selection put below.
    let below = lower.iter().copied().max_by(&cmp).map_or(upper, &value);
    mean_of_pair(below, upper)
}

/// [`median`] of a few values (sorted in place, [`sort_few`]).
pub fn median_of_few(v: &mut [f64]) -> f64 {
    sort_few(v);
    median_of_sorted(v)
}

/// Sorts a few values in place, ascending (insertion: small code, quick on a short window).
pub fn sort_few(v: &mut [f64]) {
    for i in 1..v.len() {
        let mut j = i;
        while j > 0 && v[j - 1] > v[j] {
            v.swap(j - 1, j);
            j -= 1;
        }
    }
}

/// [`median`] of values in order, ascending or descending (the middle pair's mean does not
/// depend on which); NaN for none.
#[inline]
pub fn median_of_sorted(v: &[f64]) -> f64 {
    let m = v.len();
    if m == 0 {
        f64::NAN
    } else if m % 2 == 1 {
        v[m / 2]
    } else {
        mean_of_pair(v[m / 2 - 1], v[m / 2])
    }
}

/// The median of an even count from its middle pair, lower first.
#[inline]
fn mean_of_pair(lower: f64, upper: f64) -> f64 {
    0.5 * (lower + upper)
}

/// 1σ of zero-mean normal values from the median of their absolute values `abs` (reordered in
/// place): an outlier moves it by at most one rank. NaN for none.
pub fn sigma_from_abs(abs: &mut [f64]) -> f64 {
    NORMAL_SIGMA_PER_MEDIAN_ABS * median(abs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_of_an_even_count_is_the_mean_of_the_middle_pair() {
        // Exact in binary (halves of small integers): equality is the right test.
        let mut v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(median(&mut v), 2.5);
        let mut v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(median_of_few(&mut v), 2.5);
        let mut v = [5.0, 1.0, 3.0];
        assert_eq!(median(&mut v), 3.0);
        assert!(median(&mut []).is_nan());
    }

    #[test]
    fn selection_and_sorting_give_the_same_median_bit_for_bit() {
        // A deterministic scramble of 1..=n scaled by an irrational step, odd and even n: the
        // host's selection and the screening's sort must agree to the bit (the firmware's
        // outlier verdicts are compared with the host's).
        for n in 1..40usize {
            let mut a: [f64; 40] = [0.0; 40];
            for (k, x) in a[..n].iter_mut().enumerate() {
                *x = ((k * 17 + 5) % n) as f64 * core::f64::consts::SQRT_2;
            }
            let mut b = a;
            let (m1, m2) = (median(&mut a[..n]), median_of_few(&mut b[..n]));
            assert_eq!(m1.to_bits(), m2.to_bits(), "n = {n}");
            let mut rev = b;
            rev[..n].reverse();
            assert_eq!(median_of_sorted(&rev[..n]).to_bits(), m2.to_bits());
        }
    }

    #[test]
    fn counts_and_float_bits_select_as_their_values() {
        let mut counts = [60u32, 59, 60, 61];
        assert_eq!(median_by(&mut counts, Ord::cmp, f64::from), 60.0);
        let mut bits = [3.0f64, 0.5, 2.0, 1.0].map(f64::to_bits);
        assert_eq!(median_by(&mut bits, Ord::cmp, f64::from_bits), 1.5);
    }

    #[test]
    fn sigma_from_abs_recovers_a_normal_sigma() {
        // The normal quantiles at 1/8 … 7/8 step of a σ = 2 variable, |x|: their median is
        // σ·Φ⁻¹(3/4) = 2 × 0.674490, so the estimate is 2 to the 5 digits of 1.4826.
        let z = [
            -1.150349, -0.674490, -0.318639, 0.0, 0.318639, 0.674490, 1.150349,
        ];
        let mut abs = z.map(|x: f64| (2.0 * x).abs());
        let s = sigma_from_abs(&mut abs);
        assert!((s - 2.0).abs() < 2.0 * 1e-4, "{s}");
    }
}
