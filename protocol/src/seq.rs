//! Sequence-number bookkeeping on the receiving side: frames that vanished entirely (a damaged
//! delimiter can merge two frames into one bad one) show up as gaps.

/// What one received sequence number says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeqEvent {
    /// The first frame seen.
    First,
    /// The expected next number.
    InOrder,
    /// `missing` frames were skipped before this one.
    Gap {
        /// How many numbers were skipped.
        missing: u32,
    },
    /// A number already seen or far behind: the sender restarted (or a duplicate).
    Restart,
}

/// Tracks the link sequence numbers of one direction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SeqTracker {
    next: Option<u32>,
    /// Frames received.
    pub received: u64,
    /// Numbers skipped in total.
    pub missing: u64,
    /// Times the sequence went back (sender restart or duplicate).
    pub restarts: u64,
}

/// A jump forward larger than this is taken for a restart, not for lost frames.
const MAX_GAP: u32 = 1 << 30;

impl SeqTracker {
    /// A tracker that has seen nothing.
    pub fn new() -> Self {
        Self::default()
    }

    /// Records `seq`.
    pub fn observe(&mut self, seq: u32) -> SeqEvent {
        self.received += 1;
        let ev = match self.next {
            None => SeqEvent::First,
            Some(n) if n == seq => SeqEvent::InOrder,
            Some(n) => {
                let d = seq.wrapping_sub(n);
                if d < MAX_GAP {
                    self.missing += u64::from(d);
                    SeqEvent::Gap { missing: d }
                } else {
                    self.restarts += 1;
                    SeqEvent::Restart
                }
            }
        };
        self.next = Some(seq.wrapping_add(1));
        ev
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_wrap_and_restarts() {
        let mut t = SeqTracker::new();
        assert_eq!(t.observe(5), SeqEvent::First);
        assert_eq!(t.observe(6), SeqEvent::InOrder);
        assert_eq!(t.observe(9), SeqEvent::Gap { missing: 2 });
        assert_eq!(t.observe(0), SeqEvent::Restart);
        let mut w = SeqTracker::new();
        w.observe(u32::MAX);
        assert_eq!(w.observe(1), SeqEvent::Gap { missing: 1 });
        assert_eq!((w.missing, t.missing, t.restarts), (1, 2, 1));
    }
}
