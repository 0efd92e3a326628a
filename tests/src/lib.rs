//! End-to-end tests that cross crates live in `tests/`; the command line's own end-to-end tests
//! live next to it in `tools/tests/`, where cargo builds the `asbuilt` binary for them.
