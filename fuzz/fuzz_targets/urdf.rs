#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| softcap_fuzz::fuzz("urdf", data));
