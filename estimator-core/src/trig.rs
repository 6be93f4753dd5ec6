//! Sine and cosine of the model's angles (platform attitude, latitude), for `|x| < 2²⁰·π/2`.
//!
//! Why not `libm::sincos`: libm reduces any argument, and its reduction for `|x| ≥ 2²⁰·π/2`
//! (Payne–Hanek, `rem_pio2_large`) plus its dispatch cost 2.3 KB of the firmware's 64-KiB
//! budget (issue 10), for arguments this filter never passes: its angles are the platform's
//! attitude angles (one grows with the Earth's turn under the platform: to 15.4 rad over the
//! paper's 60-h run, still 10⁵ times below the limit) and the site's latitude. Here the argument is reduced by Cody–Waite in
//! up to three parts of π/2 (good to 151 bits, enough for every `|x| < 2²⁰·π/2`), then the same
//! minimax polynomials as fdlibm's `__kernel_sin`/`__kernel_cos` are evaluated. For
//! `|x| ≤ π/4` the result is libm's bit for bit; beyond, it is within 1 ulp of it (tests below).
//! For `|x| ≥ 2²⁰·π/2` (1.6·10⁶ rad) and for non-finite `x` the result is NaN: an angle that
//! large means the filter has diverged, and a NaN makes that visible to its health checks
//! instead of hiding it behind a plausible sine.
//!
//! The constants are fdlibm's (e_rem_pio2.c, k_sin.c, k_cos.c: "Copyright (C) 1993 by Sun
//! Microsystems, Inc. All rights reserved. Developed at SunPro, a Sun Microsystems, Inc.
//! business. Permission to use, copy, modify, and distribute this software is freely granted,
//! provided that this notice is preserved.").

/// 2/π rounded to 53 bits. The constants are given as their bits, as in fdlibm's sources.
const INV_PIO2: f64 = f64::from_bits(0x3FE4_5F30_6DC9_C883);
/// 1.5·2⁵²: adding and subtracting it rounds to the nearest integer.
const TO_INT: f64 = 1.5 / f64::EPSILON;
/// π/2 in three 33-bit parts, each with the tail of π/2 left after it, and the loss of
/// exponent (cancellation) beyond which the next part is needed.
const PIO2_PARTS: [(f64, f64, i32); 3] = [
    (
        f64::from_bits(0x3FF9_21FB_5440_0000),
        f64::from_bits(0x3DD0_B461_1A62_6331),
        16,
    ),
    (
        f64::from_bits(0x3DD0_B461_1A60_0000),
        f64::from_bits(0x3BA3_198A_2E03_7073),
        49,
    ),
    (
        f64::from_bits(0x3BA3_198A_2E00_0000),
        f64::from_bits(0x397B_839A_2520_49C1),
        i32::MAX,
    ),
];
/// Upper bound of the reduced range (exclusive), as the high word of |x|: 2²⁰·π/2.
const MAX_HIGH_WORD: u32 = 0x4139_21fb;
/// 2⁻²⁷·√2 as the high word of |x|: below, sin x = x and cos x = 1 to the ulp.
const TINY_HIGH_WORD: u32 = 0x3e46_a09e;
/// π/4 as the high word of |x|: no reduction at or below.
const PIO4_HIGH_WORD: u32 = 0x3fe9_21fb;

/// `(sin x, cos x)`; NaN for `|x| ≥ 2²⁰·π/2` and for non-finite `x` (see the module's doc).
#[inline(never)]
pub fn sincos(x: f64) -> (f64, f64) {
    let high = ((x.to_bits() >> 32) as u32) & 0x7fff_ffff;
    if high < TINY_HIGH_WORD {
        return (x, 1.0); // both exact to the ulp, and sin(−0) = −0
    }
    if high <= PIO4_HIGH_WORD {
        return (k_sin(x, 0.0, false), k_cos(x, 0.0));
    }
    if high >= MAX_HIGH_WORD {
        return (f64::NAN, f64::NAN);
    }
    reduced(x, high)
}

/// `sincos` of `x` beyond π/4: reduce to `n·π/2 + (y0 + y1)`, `|y0 + y1| ≤ π/4`, and rotate
/// by the quadrant `n`. Out of line, so the common small-angle path stays short.
#[inline(never)]
fn reduced(x: f64, high: u32) -> (f64, f64) {
    let f_n = (x * INV_PIO2 + TO_INT) - TO_INT;
    let exponent = |v: f64| ((v.to_bits() >> 52) & 0x7ff) as i32;
    let ex = (high >> 20) as i32;
    // First part: x − n·p₁ is exact (p₁ has 33 bits, |n| < 2²⁰); each further part is used
    // only when the result has cancelled so far that the previous tail no longer suffices.
    let (p1, p1t, _) = PIO2_PARTS[0];
    let mut r = x - f_n * p1;
    let mut w = f_n * p1t;
    let mut y0 = r - w;
    for k in 1..PIO2_PARTS.len() {
        if ex - exponent(y0) <= PIO2_PARTS[k - 1].2 {
            break;
        }
        let (p, pt, _) = PIO2_PARTS[k];
        let t = r;
        w = f_n * p;
        r = t - w;
        w = f_n * pt - ((t - r) - w);
        y0 = r - w;
    }
    let y1 = (r - y0) - w;
    let (s, c) = (k_sin(y0, y1, true), k_cos(y0, y1));
    match (f_n as i32) & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// sin(x + y) for |x + y| ≤ π/4, `y` the tail of `x` when `tail` (fdlibm's `__kernel_sin`: a
/// degree-13 minimax polynomial, error < 2⁻⁵⁸·⁷).
#[inline]
fn k_sin(x: f64, y: f64, tail: bool) -> f64 {
    const S: [f64; 6] = [
        f64::from_bits(0xBFC5_5555_5555_5549),
        f64::from_bits(0x3F81_1111_1110_F8A6),
        f64::from_bits(0xBF2A_01A0_19C1_61D5),
        f64::from_bits(0x3EC7_1DE3_57B1_FE7D),
        f64::from_bits(0xBE5A_E5E6_8A2B_9CEB),
        f64::from_bits(0x3DE5_D93A_5ACF_D57C),
    ];
    let z = x * x;
    let w = z * z;
    let r = S[1] + z * (S[2] + z * S[3]) + z * w * (S[4] + z * S[5]);
    let v = z * x;
    if !tail {
        x + v * (S[0] + z * r)
    } else {
        x - ((z * (0.5 * y - v * r) - y) - v * S[0])
    }
}

/// cos(x + y) for |x + y| ≤ π/4 (fdlibm's `__kernel_cos`: a degree-14 minimax polynomial,
/// error < 2⁻⁵⁸, the 1 − z/2 split so the result is correct to < 1 ulp).
#[inline]
fn k_cos(x: f64, y: f64) -> f64 {
    const C: [f64; 6] = [
        f64::from_bits(0x3FA5_5555_5555_554C),
        f64::from_bits(0xBF56_C16C_16C1_5177),
        f64::from_bits(0x3EFA_01A0_19CB_1590),
        f64::from_bits(0xBE92_7E4F_809C_52AD),
        f64::from_bits(0x3E21_EE9E_BDB4_B1C4),
        f64::from_bits(0xBDA8_FAE9_BE88_38D4),
    ];
    let z = x * x;
    let w = z * z;
    let r = z * (C[0] + z * (C[1] + z * C[2])) + w * w * (C[3] + z * (C[4] + z * C[5]));
    let hz = 0.5 * z;
    let one_minus = 1.0 - hz;
    one_minus + (((1.0 - one_minus) - hz) + (z * r - x * y))
}

#[cfg(test)]
mod tests {
    use super::sincos;

    /// Distance in units in the last place between two finite doubles of the same sign
    /// (or both within an ulp of zero).
    fn ulps(a: f64, b: f64) -> u64 {
        let key = |v: f64| {
            let b = v.to_bits() as i64;
            if b < 0 {
                i64::MIN - b
            } else {
                b
            }
        };
        key(a).abs_diff(key(b))
    }

    /// A reproducible uniform stream in [0, 1) (SplitMix64).
    fn uniform(seed: &mut u64) -> f64 {
        *seed = seed.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = *seed;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Up to π/4 the function is libm's polynomial with no reduction: identical bits,
    /// tiny and subnormal arguments included.
    #[test]
    fn small_angles_are_libm_bit_for_bit() {
        let mut seed = 1;
        let pio4 = core::f64::consts::FRAC_PI_4;
        let check = |x: f64| {
            let (s, c) = sincos(x);
            let (ls, lc) = libm::sincos(x);
            assert_eq!(
                (s.to_bits(), c.to_bits()),
                (ls.to_bits(), lc.to_bits()),
                "x = {x:e}"
            );
        };
        [0.0, -0.0, 1e-300, 5e-324, -2e-9, 1e-8, pio4, -pio4]
            .into_iter()
            .for_each(check);
        for _ in 0..200_000 {
            // Uniform in magnitude and in exponent, both signs.
            let u = uniform(&mut seed);
            check((2.0 * u - 1.0) * pio4);
            let sign = if u < 0.5 { -1.0 } else { 1.0 };
            check(sign * pio4 * libm::exp2(-40.0 * uniform(&mut seed)));
        }
    }

    /// Beyond π/4 up to the limit, within 1 ulp of libm (libm's fast paths for |x| < 9π/4
    /// round the reduction in a different order) and nearly always identical; at multiples of
    /// π/2, where the reduction cancels most, the three-part reduction keeps the result exact
    /// to the ulp.
    #[test]
    fn reduced_angles_are_within_an_ulp_of_libm() {
        let mut seed = 7;
        let (mut n, mut differ) = (0, 0);
        let mut check = |x: f64| {
            let (s, c) = sincos(x);
            let (ls, lc) = libm::sincos(x);
            let d = ulps(s, ls).max(ulps(c, lc));
            assert!(d <= 1, "x = {x:e}: {s:e} {c:e} vs libm {ls:e} {lc:e}");
            n += 1;
            differ += usize::from(d != 0);
        };
        for k in 1..200 {
            let m = k as f64 * core::f64::consts::FRAC_PI_2;
            [m, -m, m.next_up(), m.next_down()]
                .into_iter()
                .for_each(&mut check);
        }
        let log_pio4 = libm::log2(core::f64::consts::FRAC_PI_4);
        for _ in 0..200_000 {
            let u = uniform(&mut seed);
            let mag = libm::exp2(log_pio4 + 20.5 * uniform(&mut seed));
            check(if u < 0.5 { -mag } else { mag });
        }
        check(1.647e6); // just below 2^20·π/2 = 1.647 099 3e6
        assert!(differ * 1000 < n, "{differ} of {n} differ from libm");
    }

    /// Outside the reduced range, and for NaN and ±∞: NaN, never a plausible number.
    #[test]
    fn out_of_range_is_nan() {
        for x in [
            1.7e6,
            -1.7e6,
            1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ] {
            let (s, c) = sincos(x);
            assert!(s.is_nan() && c.is_nan(), "x = {x:e}: ({s}, {c})");
        }
        let just_in = f64::from_bits((u64::from(super::MAX_HIGH_WORD) << 32) - 1);
        let (s, c) = sincos(just_in);
        assert!(s.is_finite() && c.is_finite() && (s * s + c * c - 1.0).abs() < 1e-15);
    }
}
