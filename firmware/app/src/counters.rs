//! The application's counters ([`protocol::Counters`], sent in every status frame): one place
//! that names what is counted and increments it (wrapping: a counter never panics).

use protocol::Counters;

use crate::screen::Reject;

/// Something the application counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(missing_docs)] // each variant is the counter of the same name in `protocol::Counters`
pub enum Count {
    SamplesOk,
    ReadErrors,
    FilterSteps,
    FilterErrors,
    UpdatesRejected,
    FramesRx,
    FramesRxBad,
    FramesRxMissing,
    CommandsRefused,
    FramesTx,
    CheckpointsWritten,
    CheckpointErrors,
    SamplesResync,
    Rejected(Reject),
}

/// Adds `n` to the counter of `what`.
pub fn add(c: &mut Counters, what: Count, n: u32) {
    let field = match what {
        Count::SamplesOk => &mut c.samples_ok,
        Count::ReadErrors => &mut c.read_errors,
        Count::FilterSteps => &mut c.filter_steps,
        Count::FilterErrors => &mut c.filter_errors,
        Count::UpdatesRejected => &mut c.updates_rejected,
        Count::FramesRx => &mut c.frames_rx,
        Count::FramesRxBad => &mut c.frames_rx_bad,
        Count::FramesRxMissing => &mut c.frames_rx_missing,
        Count::CommandsRefused => &mut c.commands_refused,
        Count::FramesTx => &mut c.frames_tx,
        Count::CheckpointsWritten => &mut c.checkpoints_written,
        Count::CheckpointErrors => &mut c.checkpoint_errors,
        Count::SamplesResync => &mut c.samples_resync,
        Count::Rejected(Reject::NotFinite) => &mut c.samples_nan,
        Count::Rejected(Reject::Saturated) => &mut c.samples_saturated,
        Count::Rejected(Reject::Duplicate) => &mut c.samples_duplicate,
        Count::Rejected(Reject::OutOfOrder) => &mut c.samples_out_of_order,
        Count::Rejected(Reject::Stuck) => &mut c.samples_stuck,
        Count::Rejected(Reject::Glitch) => &mut c.samples_glitch,
        Count::Rejected(Reject::Dropout) => &mut c.samples_dropout,
    };
    *field = field.wrapping_add(n);
}

/// Adds one to the counter of `what`.
pub fn bump(c: &mut Counters, what: Count) {
    add(c, what, 1);
}
