//! Which of the firmware's samples continue the recording being written, by their time stamps.
//!
//! A recording's samples strictly increase in time (sample identity is `t_s`). The firmware
//! sends samples again that are already recorded (after a reconnect, or to a restarted
//! recorder), resumes a run from a checkpoint with times that overlap the recording, restarts
//! its clock (a new run), or sends a time stamp out of line with its neighbours. Each is told
//! apart here, so that a new run is never mixed into the file and a single bad time stamp costs
//! that sample only:
//!
//! - later than the last written sample: written, unless it jumps ahead by more than
//!   [`JUMP_FACTOR`] times the last interval; such a sample is held until the next one says
//!   whether the jump was a real gap (the next comes after it: written) or a bad stamp (the next
//!   lies between: skipped, named);
//! - not later, and the same values as a recorded sample (the last [`RECENT`] kept): resent;
//! - not later, after the firmware announced a resume from a checkpoint: the overlap, skipped;
//! - not later, after the firmware restarted without a checkpoint: a new run;
//! - not later, otherwise: held; the next sample continuing the recording makes it a bad stamp,
//!   the next continuing from it a new run.
//!
//! Times beyond [`MAX_T_S`] are refused outright (the firmware counts from the gyros' start).

use std::collections::VecDeque;

use protocol::RawSample;

/// Latest plausible sample time, s (31.7 years after the gyros reached stable operation).
pub(crate) const MAX_T_S: f64 = 1e9;

/// A step forward by more than this many times the previous interval is checked against the
/// next sample before it is written (a real gap costs one sample of delay, nothing else).
pub(crate) const JUMP_FACTOR: f64 = 10.0;

/// Recorded samples remembered to recognise a resend (32 bytes each: 3.2 MB; 27 h at 1 Hz).
pub(crate) const RECENT: usize = 100_000;

/// What to do with a received sample (or with one held before it).
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Verdict {
    /// Write it: it continues the recording.
    Write(RawSample),
    /// Already recorded (a resend, or a resumed run's overlap): skip, count.
    Resent,
    /// Held until the next sample tells what it is.
    Held,
    /// A time stamp out of line with its neighbours: skip, count, name.
    Absurd(String),
    /// The firmware's clock went back to a time not recorded: another run. Stop, named.
    NewRun(String),
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Held {
    s: RawSample,
    ahead: bool,
}

/// The time line of the recording being written.
#[derive(Clone, Debug, Default)]
pub(crate) struct Timeline {
    /// (t, a) bit patterns of the last [`RECENT`] samples written, in time order.
    recent: VecDeque<(u64, [u64; 3])>,
    /// Interval between the last two samples written, s.
    last_dt: Option<f64>,
    held: Option<Held>,
    /// The firmware announced a resume: samples up to the last written are its overlap.
    overlap: bool,
    /// The firmware restarted without a checkpoint: an earlier time is a new run.
    restarted: bool,
}

fn print(s: &RawSample) -> (u64, [u64; 3]) {
    let a = s.specific_force;
    (
        s.t_s.to_bits(),
        [a[0].to_bits(), a[1].to_bits(), a[2].to_bits()],
    )
}

impl Timeline {
    /// An empty recording.
    pub(crate) fn new() -> Self {
        Self::default()
    }

    /// Time of the last sample written, s.
    pub(crate) fn last_t(&self) -> Option<f64> {
        self.recent.back().map(|p| f64::from_bits(p.0))
    }

    /// Records that `s` was written (also for samples already in a resumed file).
    pub(crate) fn written(&mut self, s: &RawSample) {
        if let Some(t) = self.last_t() {
            self.last_dt = Some(s.t_s - t);
        }
        if self.recent.len() == RECENT {
            self.recent.pop_front();
        }
        self.recent.push_back(print(s));
        self.overlap = false;
    }

    /// The firmware rebooted: `resumed` says whether it goes on with the run from a checkpoint
    /// (its times then overlap the recording) or starts again (its clock restarts at 0).
    pub(crate) fn firmware_reset(&mut self, resumed: bool) {
        self.overlap = resumed;
        self.restarted = !resumed;
    }

    /// A sample held at the end of the recording, never confirmed by a later one.
    pub(crate) fn unconfirmed(&self) -> Option<RawSample> {
        self.held.map(|h| h.s)
    }

    fn is_recorded(&self, s: &RawSample) -> bool {
        let key = print(s);
        self.recent
            .binary_search_by(|p| f64::from_bits(p.0).total_cmp(&s.t_s))
            .is_ok_and(|i| self.recent[i] == key)
    }

    /// The verdicts on `s` and on a sample held before it, in order. Every
    /// [`Verdict::Write`] is taken as written (the caller writes it or stops).
    pub(crate) fn push(&mut self, s: &RawSample) -> Vec<Verdict> {
        let mut out = Vec::new();
        if s.t_s.abs() > MAX_T_S {
            out.push(Verdict::Absurd(format!(
                "sample {}: t_s = {:e} s is beyond any run (|t_s| > {MAX_T_S:e} s)",
                s.seq, s.t_s
            )));
            return out;
        }
        let after_last = self.last_t().is_none_or(|t| s.t_s > t);
        if let Some(h) = self.held.take() {
            let name = |why: &str| {
                format!(
                    "sample {}: t_s = {:?} s {why} (the samples around it: {:?} s and {:?} s)",
                    h.s.seq,
                    h.s.t_s,
                    self.last_t().unwrap_or(f64::NAN),
                    s.t_s
                )
            };
            match (h.ahead, after_last) {
                (true, _) if s.t_s > h.s.t_s => {
                    // A real gap: written, and `s` is judged against it.
                    self.written(&h.s);
                    out.push(Verdict::Write(h.s));
                }
                (true, true) => out.push(Verdict::Absurd(name("jumps ahead of its neighbours"))),
                (false, true) => out.push(Verdict::Absurd(name("goes back before its neighbours"))),
                (_, false) if self.is_recorded(s) => {
                    self.held = Some(h);
                    out.push(Verdict::Resent);
                    return out;
                }
                (_, false) => {
                    out.push(Verdict::NewRun(self.new_run(if h.ahead {
                        s
                    } else {
                        &h.s
                    })));
                    return out;
                }
            }
        }
        out.push(self.place(s));
        out
    }

    /// The verdict on `s` with nothing held.
    fn place(&mut self, s: &RawSample) -> Verdict {
        let Some(t) = self.last_t() else {
            self.written(s);
            return Verdict::Write(*s);
        };
        if s.t_s > t {
            if self.last_dt.is_some_and(|dt| s.t_s - t > JUMP_FACTOR * dt) {
                self.held = Some(Held { s: *s, ahead: true });
                return Verdict::Held;
            }
            self.written(s);
            return Verdict::Write(*s);
        }
        if self.restarted {
            return Verdict::NewRun(self.new_run(s));
        }
        if self.overlap || self.is_recorded(s) {
            return Verdict::Resent;
        }
        self.held = Some(Held {
            s: *s,
            ahead: false,
        });
        Verdict::Held
    }

    fn new_run(&self, s: &RawSample) -> String {
        format!(
            "sample {}: the firmware's clock went back from t_s = {:?} s (the last sample recorded) to {:?} s, a time not recorded{}: another run",
            s.seq,
            self.last_t().unwrap_or(f64::NAN),
            s.t_s,
            if self.restarted { ", after it restarted without a checkpoint" } else { "" }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(seq: u32, t: f64, a: f64) -> RawSample {
        RawSample {
            seq,
            t_s: t,
            specific_force: [a, 0.0, 9.8],
            temp_c: f64::NAN,
        }
    }

    /// Feeds samples, writing what is to be written; returns the times written and the rest.
    fn run(tl: &mut Timeline, samples: &[RawSample]) -> (Vec<f64>, Vec<Verdict>) {
        let (mut written, mut other) = (Vec::new(), Vec::new());
        for s in samples {
            for v in tl.push(s) {
                match v {
                    Verdict::Write(w) => written.push(w.t_s),
                    Verdict::Held => {}
                    v => other.push(v),
                }
            }
        }
        (written, other)
    }

    #[test]
    fn a_spike_ahead_costs_itself_and_a_real_gap_nothing() {
        let mut tl = Timeline::new();
        let mut s: Vec<RawSample> = (0..10).map(|k| at(k, f64::from(k), 0.1)).collect();
        s.insert(5, at(99, 5000.0, 0.1)); // between 4 s and 5 s
        s.push(at(10, 3600.0, 0.1)); // a real gap: the next continues after it
        s.push(at(11, 3601.0, 0.1));
        let (w, other) = run(&mut tl, &s);
        let mut want: Vec<f64> = (0..10).map(f64::from).collect();
        want.extend([3600.0, 3601.0]);
        assert_eq!(w, want);
        assert_eq!(other.len(), 1);
        assert!(
            matches!(&other[0], Verdict::Absurd(m) if m.contains("sample 99") && m.contains("5000"))
        );
    }

    #[test]
    fn a_resend_is_skipped_and_a_clock_restart_is_another_run() {
        let mut tl = Timeline::new();
        let first: Vec<RawSample> = (0..20).map(|k| at(k, f64::from(k), 0.1)).collect();
        let (w, other) = run(&mut tl, &first);
        assert_eq!((w.len(), other.len()), (20, 0));
        // Resent (same values), then new ones: 15..19 skipped, 20.. written.
        let again: Vec<RawSample> = (15..25).map(|k| at(k, f64::from(k), 0.1)).collect();
        let (w, other) = run(&mut tl, &again);
        assert_eq!(w, (20..25).map(f64::from).collect::<Vec<_>>());
        assert_eq!(other, vec![Verdict::Resent; 5]);
        // The clock restarts at 0 with other readings: held, then another run.
        let new_run: Vec<RawSample> = (0..3).map(|k| at(k, f64::from(k), 0.2)).collect();
        let (w, other) = run(&mut tl, &new_run);
        assert!(w.is_empty());
        assert!(
            matches!(&other[0], Verdict::NewRun(m) if m.contains("sample 0") && m.contains("24.0"))
        );
    }

    #[test]
    fn a_resumed_run_overlaps_and_a_restarted_firmware_is_another_run_at_once() {
        let mut tl = Timeline::new();
        run(
            &mut tl,
            &(0..20)
                .map(|k| at(k, f64::from(k), 0.1))
                .collect::<Vec<_>>(),
        );
        tl.firmware_reset(true);
        let (w, other) = run(
            &mut tl,
            &(12..22)
                .map(|k| at(k, f64::from(k), 0.3))
                .collect::<Vec<_>>(),
        );
        assert_eq!((w, other.len()), (vec![20.0, 21.0], 8));
        tl.firmware_reset(false);
        let (_, other) = run(&mut tl, &[at(0, 0.0, 0.3)]);
        assert!(matches!(&other[0], Verdict::NewRun(m) if m.contains("restarted")));
    }

    #[test]
    fn a_single_stamp_back_or_beyond_any_run_is_skipped_by_name() {
        let mut tl = Timeline::new();
        let mut s: Vec<RawSample> = (0..60).map(|k| at(k, f64::from(k), 0.1)).collect();
        s.insert(30, at(300, 1e308, 0.1));
        s.insert(40, at(400, 3.5, 0.7));
        let (w, other) = run(&mut tl, &s);
        assert_eq!(
            w,
            (0..60).map(f64::from).collect::<Vec<_>>(),
            "every real sample"
        );
        assert_eq!(other.len(), 2);
        assert!(
            matches!(&other[0], Verdict::Absurd(m) if m.contains("sample 300") && m.contains("beyond"))
        );
        assert!(
            matches!(&other[1], Verdict::Absurd(m) if m.contains("sample 400") && m.contains("back"))
        );
    }
}
