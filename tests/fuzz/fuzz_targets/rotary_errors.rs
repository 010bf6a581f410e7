#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::rotary_errors(data));
