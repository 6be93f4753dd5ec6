//! `driftid` library: everything the binary does, callable from tests.
pub mod identify;
