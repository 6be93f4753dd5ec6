//! Sample screening: what a sample must pass before it is averaged. Every rejection has a reason,
//! counted by the caller ([`crate::counters::Count`]).
//!
//! Two stages:
//! 1. **The firmware's own checks**, on arrival ([`Screen::check`]): a non-finite time or value,
//!    saturation (the sensor's flag or the configured limit) and the time order (a duplicate or
//!    an earlier time). The core has no saturation limit or time-order rule for a stream, and a
//!    sample that fails them has no place in the stream at all.
//! 2. **The core's screening** ([`estimator_core::screening::Screener`], the one implementation
//!    the host's batch screening also runs): dropouts to zero, stuck axes and glitches, each
//!    sample judged against its neighbours on both sides. A sample therefore comes out
//!    `half_window` samples after it went in ([`Screen::push`]), with its verdict; the rest come
//!    out at the end of the run ([`Screen::drain`]).

use estimator_core::screening::{flag, ScreenConfig, Screener};
use estimator_core::Sample;
use protocol::Config;

/// Why a sample was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reject {
    /// A NaN or infinite time or axis.
    NotFinite,
    /// Beyond the saturation limit (or flagged saturated by the sensor).
    Saturated,
    /// The same time as the previous sample.
    Duplicate,
    /// Before the previous sample, or before 0.
    OutOfOrder,
    /// Part of a run of identical readings on an axis (the core's stuck test).
    Stuck,
    /// Every axis reads exactly zero (a dropout; the core's test).
    Dropout,
    /// An outlier against its neighbours (a glitch; the core's test).
    Glitch,
}

impl Reject {
    /// The reason for the core screening's flags (`None`: accepted).
    pub fn of_flags(f: u8) -> Option<Reject> {
        if f == 0 {
            None
        } else if f & flag::NON_FINITE != 0 {
            Some(Reject::NotFinite)
        } else if f & flag::ZERO != 0 {
            Some(Reject::Dropout)
        } else if f & flag::STUCK != 0 {
            Some(Reject::Stuck)
        } else {
            Some(Reject::Glitch)
        }
    }
}

/// The thresholds of the core's screening the firmware runs (the core's defaults).
pub fn screen_config() -> ScreenConfig {
    ScreenConfig::default()
}

/// A sample out of the screening with its verdict: `Ok` to average it, `Err` (why) when the
/// core's screening rejected it.
pub type Screened = (Sample, Result<(), Reject>);

fn verdict(f: u8) -> Result<(), Reject> {
    Reject::of_flags(f).map_or(Ok(()), Err)
}

/// The screening state of a run.
#[derive(Clone, Debug)]
pub struct Screen {
    /// Time of the last sample that passed the firmware's checks (the order check's reference).
    pub last_t_s: Option<f64>,
    screener: Screener,
}

impl Screen {
    /// A run with configuration `config` whose last sample was at `last_t_s`.
    pub fn new(config: &Config, last_t_s: Option<f64>) -> Self {
        // The stuck-run threshold assumes a day of samples (α = 1e-6 false alarms per day).
        let per_day = (config.sample_rate_hz * 86_400.0).clamp(1.0, 1e12) as usize;
        Screen {
            last_t_s,
            screener: Screener::new(config.raw_sigma_mps2, screen_config(), per_day),
        }
    }

    /// The firmware's checks of `s` on arrival (nothing is recorded).
    pub fn check(&self, s: &Sample, saturated: bool, limit_mps2: f64) -> Result<(), Reject> {
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
        Ok(())
    }

    /// Checks `s` ([`Screen::check`]) and, if it passes, hands it to the core's screening:
    /// `Err` says why it was refused on arrival; `Ok(Some(..))` is the sample `half_window`
    /// back, now judged.
    pub fn push(
        &mut self,
        s: &Sample,
        saturated: bool,
        limit_mps2: f64,
    ) -> Result<Option<Screened>, Reject> {
        self.check(s, saturated, limit_mps2)?;
        self.last_t_s = Some(s.t_s);
        Ok(self.screener.push(*s).map(|(s, f)| (s, verdict(f))))
    }

    /// The end of the run: the oldest sample still held, judged with the neighbours there are
    /// (`None` when none is left).
    pub fn drain(&mut self) -> Option<Screened> {
        self.screener.drain().map(|(s, f)| (s, verdict(f)))
    }

    /// The sample that came out last, if it was accepted (restoring a checkpoint: the sample
    /// that opened the averaging window the checkpoint was taken in).
    pub fn last_accepted(&self) -> Option<Sample> {
        self.screener
            .last_emitted()
            .and_then(|(s, f)| (f == 0).then_some(s))
    }

    /// Bytes [`Screen::save`] writes at most.
    pub fn state_len() -> usize {
        Screener::state_len(&screen_config())
    }

    /// Writes the core screening's state into `buf` (for a checkpoint); returns its length.
    pub fn save(&self, buf: &mut [u8]) -> Option<usize> {
        self.screener.save(buf)
    }

    /// Restores the core screening's state from a checkpoint ([`Screen::save`]).
    pub fn load(&mut self, bytes: &[u8]) -> Option<()> {
        self.screener.load(bytes)
    }
}
