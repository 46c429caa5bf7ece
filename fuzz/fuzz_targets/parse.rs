//! Any bytes → `Container::parse` (with and without the checksum, so the fuzzer gets past it):
//! an error or a material, never a panic. A neural material re-serializes; a JPEG one is decoded
//! by the `decode` and `jpeg` targets.
#![no_main]
use libfuzzer_sys::fuzz_target;
use nmat_core::{Container, ParseOptions};

fuzz_target!(|data: &[u8]| {
    let _ = Container::parse(data);
    if let Ok(m) = Container::parse_with(data, ParseOptions { verify_checksum: false }) {
        // Everything parse accepted can be described and re-serialized.
        let _ = m.bppc();
        let Some(spec) = m.to_spec() else { return };
        let bytes = spec.to_bytes().expect("an accepted file re-serializes");
        Container::parse(&bytes).expect("and parses again");
    }
});
