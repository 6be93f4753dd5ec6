//! Whether the CPU has AVX2, for the hot loops that have a build for it (x86-64 only).
//!
//! A loop compiled for AVX2 runs on four lanes where the portable x86-64 build (SSE2) has two.
//! The pattern: the body `#[inline(always)]`, one wrapper with `#[target_feature(enable =
//! "avx2")]` calling it, and the caller choosing the wrapper when [`has_avx2`] says so. The
//! same source, the same operations in the same order and no fused multiply-add (Rust does
//! not contract `a * b + c`), so the same bits: a faster build of one implementation, not a
//! second one. Users: [`crate::Ekf::step`], the host's smoother.

// Detected once and cached: RustCrypto's `cpufeatures` (no_std), not std's
// `is_x86_feature_detected!`, which this crate cannot use without std.
#[cfg(target_arch = "x86_64")]
cpufeatures::new!(cpu_avx2, "avx2");

use core::sync::atomic::{AtomicBool, Ordering::Relaxed};

/// Set by [`force_portable`].
static PORTABLE: AtomicBool = AtomicBool::new(false);

/// `true`: [`has_avx2`] answers `false` from now on, so every caller takes the portable build;
/// `false`: the CPU's answer again. For the tests that compare the two builds' bits, and to
/// rule the AVX2 build out when in doubt.
pub fn force_portable(on: bool) {
    PORTABLE.store(on, Relaxed);
}

/// Whether this CPU (and its OS) supports AVX2 and the AVX2 builds are not ruled out
/// ([`force_portable`]); `false` off x86-64.
#[inline]
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        !PORTABLE.load(Relaxed) && cpu_avx2::get()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
