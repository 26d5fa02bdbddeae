#![cfg_attr(feature = "libfuzzer", no_main)]
spsr_fuzz::fuzz_target!(spsr_fuzz::harness::mesh);
