//! `driftid` library: everything the binary does, callable from tests.
//!
//! - [`recording`]: the CSV recording format (streaming reader with located errors, writer).
//! - [`simulate`]: the truth simulator (independent DCM kinematics, injectable effects).
//! - [`identify`]: the converged identification (EKF passes, iterated smoother, Cramér–Rao bound).
//! - [`catalog`]: the physical effects the user can add by name.
//! - [`diagnose`]: model vs measurements, score tests of the missing effects, the model ladder.
//! - [`report`]: the self-contained HTML report and its plots.
//! - [`link`]: the host end of the telemetry link (record, HIL replay).
//! - [`output`]: atomic writes of every output file; an output never overwrites an input.
//! - [`cli`]: one module per `driftid` subcommand.
pub mod catalog;
pub mod diagnose;
pub mod format;
pub mod identify;
pub mod link;
pub mod output;
pub mod progress;
pub mod recording;
pub mod report;
pub mod simulate;
pub mod stats;
pub mod cli {
    //! One module per subcommand: its arguments and its `run`.
    pub mod args;
    pub mod bench;
    pub mod common;
    pub mod demo;
    pub mod diagnose;
    pub mod identify;
    pub mod record;
    pub mod replay;
    pub mod report;
    pub mod simulate;
}
