//! How many passes over the measurements this process has made, by kind: where a run's time
//! goes, beside its clock in `DRIFTID_TIMING`'s notes ([`crate::progress`]). A fit far from
//! its start or with many states takes more passes, and each of the passes of a model of n
//! states costs about (n / 15)² of the paper model's.

use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

/// Linearised passes of the smoother's filter ([`super::smoother`]): the Gauss–Newton
/// iterations of every fit and refit, and the replays that score candidates.
static LINEARISED: AtomicUsize = AtomicUsize::new(0);
/// Extended Kalman filter passes (the single pass and the second pass of a fit's start, the
/// latitude profile's screen).
static EKF: AtomicUsize = AtomicUsize::new(0);
/// Of either kind, the passes' state-steps in units of one paper-model pass's (n² × updates,
/// over 15² × 3 601: a 60-h run's).
static WEIGHED: AtomicUsize = AtomicUsize::new(0);

/// Notes one pass of `states` states over `updates` filter periods.
pub(crate) fn count(linearised: bool, states: usize, updates: usize) {
    match linearised {
        true => &LINEARISED,
        false => &EKF,
    }
    .fetch_add(1, Relaxed);
    // Thousandths of a paper pass, so that short runs count too.
    WEIGHED.fetch_add(states * states * updates * 1000 / (15 * 15 * 3601), Relaxed);
}

/// "linearised L, EKF E, ≈ W paper passes" so far.
pub fn so_far() -> String {
    format!(
        "passes: {} linearised, {} EKF, ≈ {:.1} of the paper model's over 60 h",
        LINEARISED.load(Relaxed),
        EKF.load(Relaxed),
        WEIGHED.load(Relaxed) as f64 / 1000.0
    )
}
