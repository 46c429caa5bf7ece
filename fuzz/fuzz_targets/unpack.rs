//! Any bytes → the packed-latents path (FORMAT.md §12): `unpacked_len`, `unpack_into` (with and
//! without the checksum, into memory of the announced size, which the format bounds by 256× the
//! stream), then parsing what came out; and for a fixed-rate neural file, `pack` either refuses
//! it by name or gives a file that unpacks to the very same bytes. Never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use nmat_core::{Container, Error, ParseOptions, pack, unpack, unpack_into, unpacked_len};

const NO_CHECKSUM: ParseOptions = ParseOptions { verify_checksum: false };

fuzz_target!(|data: &[u8]| {
    let _ = unpack(data, ParseOptions::default());
    match unpacked_len(data) {
        Ok(Some(n)) => {
            assert!(n <= 256 * (data.len() + 64) + data.len(), "{n} bytes from {}", data.len());
            let mut out = vec![0u8; n];
            if let Ok(len) = unpack_into(data, NO_CHECKSUM, &mut out) {
                assert_eq!(len, n);
                let _ = Container::parse(&out);
            }
            // Too little memory is refused, never overrun.
            if n > 0 {
                let short = unpack_into(data, NO_CHECKSUM, &mut out[..n - 1]);
                assert!(short.is_err());
            }
        }
        Ok(None) => {
            if Container::parse(data).is_ok_and(|m| m.neural().is_some()) {
                match pack(data) {
                    Ok(packed) => {
                        let back = unpack(&packed, ParseOptions::default()).expect("unpacks");
                        assert!(back.as_ref() == data, "packing lost bytes");
                    }
                    Err(Error::BadArgument { .. }) => {}
                    Err(e) => panic!("a parsed file failed to pack: {e}"),
                }
            }
        }
        Err(_) => {}
    }
});
