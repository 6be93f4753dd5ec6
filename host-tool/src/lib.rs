//! `driftid` library: everything the binary does, callable from tests.
pub mod identify;
pub mod recording;
pub mod simulate;
pub mod cli {
    pub mod simulate;
}
