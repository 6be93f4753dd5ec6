//! # sampling
//!
//! What happens to raw accelerometer samples before the EKF, shared by firmware and host:
//! - [`screening`]: raw-sample screening (glitches, stuck/dead channels, non-finite) before averaging.
//! - [`averaging`]: raw samples → filter-period means tagged at the mean sample time.
//! - [`robust`]: the median and the 1σ it gives (the screening's, and the host's statistics').
//!
//! A crate of its own, apart from the EKF in `estimator-core` (which re-exports both modules
//! under the same paths), so that the firmware can optimise it for size while the EKF keeps
//! its speed (Cargo.toml, `[profile.firmware]`). `no_std`, no heap.
#![no_std]
#![warn(missing_docs)]

pub mod averaging;
pub mod robust;
pub mod screening;

pub use averaging::{Averager, Measurement, Sample};

/// √x, IEEE 754 (correctly rounded), for every crate of the workspace (the EKF's too).
///
/// On the firmware's Cortex-M7 (FPv5-D16, double precision: `target-cpu=cortex-m7` in
/// .cargo/config.toml) the FPU's `VSQRT.F64`: 14 cycles instead of `libm::sqrt`'s software
/// loop, and 420 B of libm's code less in the image (issue 10). Elsewhere `libm::sqrt`. Both are
/// correctly rounded square roots (IEEE 754 requires it of `VSQRT`; libm's is exact-rounding
/// by construction), so firmware and host results stay bit-identical. An FPU without double
/// precision fails the build (the assembler rejects `vsqrt.f64`), never silently.
#[inline]
pub fn sqrt(x: f64) -> f64 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        // Through core registers and d7 (caller-saved): on stable Rust the `dreg` operand
        // classes need target features that `target-cpu` does not declare to rustc.
        let bits = x.to_bits();
        let (lo, hi): (u32, u32);
        // SAFETY: pure arithmetic on registers; d7 is declared clobbered.
        unsafe {
            core::arch::asm!(
                "vmov d7, {lo}, {hi}",
                "vsqrt.f64 d7, d7",
                "vmov {lo}, {hi}, d7",
                lo = inout(reg) bits as u32 => lo,
                hi = inout(reg) (bits >> 32) as u32 => hi,
                out("d7") _,
                options(pure, nomem, nostack, preserves_flags),
            );
        }
        f64::from_bits(u64::from(hi) << 32 | u64::from(lo))
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrt(x)
    }
}

/// `ceil(x) as usize`, exactly (saturating, NaN → 0, as the cast), without libm's `ceil`: the
/// float-to-integer cast truncates toward zero, one up if that lost a fraction. -128 B of
/// libm in the firmware image, and fewer instructions (issue 10).
#[inline]
pub fn ceil_usize(x: f64) -> usize {
    let n = x as usize;
    if (n as f64) < x {
        n.saturating_add(1)
    } else {
        n
    }
}

#[cfg(test)]
mod tests {
    /// `ceil_usize` is `ceil(x) as usize` bit for bit, at the edges (fractions, negatives, NaN,
    /// infinities, saturation, the last fractional doubles) and on a spread of values.
    #[test]
    fn ceil_usize_is_ceil_as_usize() {
        let edges = [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            2.0,
            1e-300,
            -1e-300,
            4_294_967_295.5,
            4_503_599_627_370_495.5,
            1.8e19,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        let spread = (0..10_000).map(|i| (i as f64 - 5_000.0) * 0.013_7);
        for x in edges.into_iter().chain(spread) {
            assert_eq!(super::ceil_usize(x), libm::ceil(x) as usize, "x = {x:e}");
        }
    }

    /// The firmware's `VSQRT.F64` is checked against this on QEMU (bit-identical estimates);
    /// on the host `sqrt` is libm's, exact on perfect squares and correctly rounded.
    #[test]
    fn sqrt_is_correctly_rounded() {
        for i in 0..1000u32 {
            let r = f64::from(i) * 0.25;
            assert_eq!(super::sqrt(r * r), r);
        }
        assert_eq!(super::sqrt(2.0), core::f64::consts::SQRT_2);
        assert!(super::sqrt(-1.0).is_nan());
    }
}
