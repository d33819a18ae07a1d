#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| livegesture_fuzz::serve_protocol(data));
