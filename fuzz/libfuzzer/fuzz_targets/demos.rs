#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| ess_fuzz::demos(data));
