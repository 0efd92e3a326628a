//! The pieces of the `asbuilt` command that other crates and tests use: reading and writing
//! scan files, and the simulated print cell on the wire. The subcommands themselves live in the
//! binary.

pub mod scan_io;
pub mod sim;
