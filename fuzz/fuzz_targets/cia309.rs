#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cangate_fuzz_harness::cia309(data));
