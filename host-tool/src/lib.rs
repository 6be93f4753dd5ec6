//! `driftid` library: everything the binary does, callable from tests.
//!
//! - [`recording`]: the CSV recording format (streaming reader with located errors, writer).
//! - [`simulate`]: the truth simulator (independent DCM kinematics, injectable effects).
//! - [`quality`]: data quality — raw-sample screening, metadata and physics checks, findings.
//! - [`identify`]: the converged identification (EKF passes, iterated smoother, Cramér–Rao bound).
//! - [`catalog`]: the physical effects the user can add by name.
//! - [`consistency`]: the one definition of a consistent model (NIS band, whiteness, floor).
//! - [`effects_file`]: effects defined by the user in a TOML file (`--effects FILE`).
//! - [`diagnose`]: model vs measurements, score tests of the missing effects, the model ladder.
//! - [`report`]: the self-contained HTML report and its plots.
//! - [`link`]: the host end of the telemetry link (record, HIL replay).
//! - [`output`]: atomic writes of every output file; an output never overwrites an input.
//! - [`cli`]: one module per `driftid` subcommand.
pub mod assess;
pub mod catalog;
pub mod consistency;
pub mod diagnose;
pub mod effects_file;
pub mod format;
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub mod heap;
pub mod identify;
pub mod link;
pub mod output;
pub mod plan;
pub mod pool;
pub mod progress;
pub mod quality;
pub mod recording;
pub mod report;
pub mod simulate;
pub mod stats;
pub mod steps;
pub mod cli {
    //! One module per subcommand: its arguments and its `run`.
    pub mod args;
    pub mod bench;
    pub mod common;
    pub mod demo;
    pub mod diagnose;
    pub mod identify;
    pub mod joint;
    pub(crate) mod joint_report;
    pub mod plan;
    pub mod record;
    pub mod replay;
    pub mod report;
    pub mod simulate;
}
