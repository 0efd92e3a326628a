//! One integration-test binary for the whole workspace. Every binary here links the agent, the
//! tools and rerun; one link instead of one per file keeps a cold CI build inside its disk and
//! time budget. Run one group with `cargo test -p asbuilt-tests --test e2e autzen::`.

mod agent;
mod autzen;
mod bunny;
mod calibrate;
mod crash;
mod fuzz;
mod inspect_methods;
mod profiler;
mod recording;
mod report_html;
mod scan_files;
mod sim;
mod viewer;
