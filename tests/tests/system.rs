//! The system tests, one test binary: each module is the tests of one area (a driver
//! against its emulator, an interop with a real client, the gateway end to end). One
//! binary builds once, and libtest runs the tests of every area beside each other
//! (`RUST_TEST_THREADS` in `.cargo/config.toml`); those that share a peer (LinuxCNC,
//! a fixed port) take their module's lock. Run one area with
//! `cargo test -p system-tests --test system a_real_linuxcnc::`.

// First in name order, so libtest starts it first: the cases against the one real
// LinuxCNC, about six minutes in one test, while the other areas run beside it.
mod a_real_linuxcnc;

// What several areas share.
mod canopen_common;
mod controller_tables_reader;
mod gige_common;
mod grbl_common;
mod modbus_common;

mod canopen_demo;
mod canopen_driver;
mod canopen_interop;
mod canopen_localnode;
mod canopen_socketcan;
mod compensation;
mod controller_tables;
mod dnc;
mod dnc_programs;
mod dnc_scan;
mod errormap_scan;
mod errormap_verify;
mod fault_matrix;
mod gige_bad_frames;
mod gige_demo;
mod gige_driver;
mod gige_interop;
mod gige_rig_process;
mod grbl_demo;
mod grbl_driver;
mod grbl_firmware_diff;
mod grbl_firmware_system;
mod grbl_interop;
mod grbl_stream;
mod iso230;
mod layout_cut;
mod layout_interop;
mod modbus_demo;
mod modbus_driver;
mod modbus_faults;
mod modbus_interop;
mod modbus_profiles;
mod ngc_corpus;
mod northbound;
mod proxy;
mod proxy_in_use;
mod proxy_rotary;
mod retrofit_workflow;
mod rewrite_paths;
mod rotary;
mod service_api;
mod service_connections;
mod service_procedures;
mod service_web;
mod volumetric;
mod volumetric_grbl;
mod web_page_stub;

/// Every file of `tests/tests` is a module here: the package does not find its tests
/// itself (`autotests = false`), so a file left out would never run.
#[test]
fn every_test_file_is_a_module_of_this_binary() {
    system_tests::assert_every_test_file_declared(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests"),
        "system",
        include_str!("system.rs"),
    );
}
