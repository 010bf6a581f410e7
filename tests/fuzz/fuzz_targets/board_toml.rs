#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::board_toml(data));
