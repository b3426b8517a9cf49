#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz::Target::Ros1Bag.run(data));
