//! The command line's own parts: what it prints, and the demo. Binary-only: the
//! library (`agent::*`) returns results and never prints.

pub(crate) mod args;
pub(crate) mod demo;
pub(crate) mod report;
pub(crate) mod servers;
