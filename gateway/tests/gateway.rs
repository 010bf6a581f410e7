//! The gateway's own tests, one test binary: the command line (each command, its outputs,
//! its refusals) and the same requests through the service's API compared kind by kind
//! (`procedures`). One binary builds once and runs its areas beside each other. Run one
//! area with `cargo test -p gateway --test gateway procedures::`.

// What several areas share.
mod common;

mod cli;
mod foreign_frames;
mod identity;
mod iso230_cli;
mod layout_cli;
mod outputs_cli;
mod procedures;
mod proxy_without_camera;
mod rotary_cli;
mod volumetric_cli;

/// Every file of `gateway/tests` is a module here: the package does not find its tests
/// itself (`autotests = false`), so a file left out would never run.
#[test]
fn every_test_file_is_a_module_of_this_binary() {
    system_tests::assert_every_test_file_declared(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests"),
        "gateway",
        include_str!("gateway.rs"),
    );
}
