#![no_main]
libfuzzer_sys::fuzz_target!(
    init: {
        // libfuzzer-sys installs a panic hook that aborts at once, before any unwinding;
        // the DXF reader catches a panic inside the dxf crate (chrono, on out-of-range
        // header dates) and refuses the file, so that hook would report a refusal as a
        // crash. The default hook is put back: a panic nobody catches still unwinds into
        // libfuzzer-sys's own catch and aborts there, so real crashes are still found.
        drop(std::panic::take_hook());
    },
    |data: &[u8]| fuzz_targets::layout_dxf(data)
);
