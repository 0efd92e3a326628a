//! The pieces of the `asbuilt` command that other crates and tests use: reading and writing
//! scan files. The subcommands themselves live in the binary; the simulated print cell is
//! `asbuilt-sim`.

pub mod scan_io;
