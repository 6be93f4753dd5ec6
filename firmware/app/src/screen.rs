//! Sample screening: what a sample must pass before it is averaged. Every rejection has a reason,
//! counted by the caller ([`crate::counters::Count`]).

use estimator_core::Sample;

/// Identical consecutive readings on one axis from which the sensor counts as stuck.
pub const STUCK_RUN: u32 = 8;

/// Why a sample was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reject {
    /// A NaN or infinite time or axis.
    NotFinite,
    /// Beyond the saturation limit (or flagged saturated by the sensor).
    Saturated,
    /// The same time as the previous accepted sample.
    Duplicate,
    /// Before the previous accepted sample, or before 0.
    OutOfOrder,
    /// An axis repeated its reading [`STUCK_RUN`] times (live sensor only).
    Stuck,
}

/// The screening state of a run: the last accepted time and, for a live sensor, the repeat
/// counts of each axis.
#[derive(Clone, Copy, Debug)]
pub struct Screen {
    /// Time of the last accepted sample.
    pub last_t_s: Option<f64>,
    prev_raw: [f64; 3],
    same: [u32; 3],
}

impl Screen {
    /// A run whose last accepted sample was at `last_t_s`.
    pub fn new(last_t_s: Option<f64>) -> Self {
        Screen {
            last_t_s,
            prev_raw: [f64::NAN; 3],
            same: [0; 3],
        }
    }

    /// Checks `s`; on success records it as the last accepted sample. `live`: a live sensor
    /// (replayed recordings may repeat values legitimately, e.g. quantised files).
    pub fn check(
        &mut self,
        s: &Sample,
        saturated: bool,
        limit_mps2: f64,
        live: bool,
    ) -> Result<(), Reject> {
        if !(s.t_s.is_finite() && s.specific_force.iter().all(|v| v.is_finite())) {
            return Err(Reject::NotFinite);
        }
        if saturated || s.specific_force.iter().any(|v| v.abs() >= limit_mps2) {
            return Err(Reject::Saturated);
        }
        if self.last_t_s == Some(s.t_s) {
            return Err(Reject::Duplicate);
        }
        if self.last_t_s.is_some_and(|t| s.t_s < t) || s.t_s < 0.0 {
            return Err(Reject::OutOfOrder);
        }
        if live {
            // A live sensor's noise (tens of LSB per sample) never repeats a reading exactly
            // STUCK_RUN times on an axis: such a run means a stuck converter or a dead bus.
            let mut stuck = false;
            for i in 0..3 {
                let v = s.specific_force[i];
                self.same[i] = if v.to_bits() == self.prev_raw[i].to_bits() {
                    self.same[i].saturating_add(1)
                } else {
                    0
                };
                self.prev_raw[i] = v;
                stuck |= self.same[i] + 1 >= STUCK_RUN;
            }
            if stuck {
                return Err(Reject::Stuck);
            }
        }
        self.last_t_s = Some(s.t_s);
        Ok(())
    }
}
