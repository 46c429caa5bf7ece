//! Every input under `fuzz/regressions/` (inputs that once crashed a fuzz target, or that probe a
//! corner worth keeping) runs in the normal suite: unpack (a packed file), parse with and without
//! the checksum, then decode a few texels through every entry point. None may panic.

use nmat_core::{ChannelMask, Container, Filter, ParseOptions, Precision, SampleRequest};
use std::path::PathBuf;

#[test]
fn fuzz_regression_inputs_never_panic() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fuzz/regressions");
    let mut count = 0;
    for target in std::fs::read_dir(&root).expect("fuzz/regressions exists") {
        let dir = target.unwrap().path();
        if !dir.is_dir() {
            continue;
        }
        for input in std::fs::read_dir(dir).unwrap() {
            let path = input.unwrap().path();
            if path.extension().is_some_and(|e| e == "md") {
                continue;
            }
            let data = std::fs::read(&path).unwrap();
            count += 1;
            // A packed input is unpacked first, as every reader does.
            let unpacked = nmat_core::unpack(&data, ParseOptions { verify_checksum: false });
            let data = unpacked.map_or(data.clone(), |u| u.into_owned());
            let _ = Container::parse(&data);
            let Ok(m) = Container::parse_with(&data, ParseOptions { verify_checksum: false })
            else {
                continue;
            };
            let mut out = [0f32; 16];
            let mut codes = [0u8; 16];
            for (x, y, mip) in [(0, 0, 0), (-1, i64::MAX, u32::MAX), (12345, -777, 3)] {
                let _ = m.decode_texel(x, y, mip, ChannelMask::ALL, &mut out);
                let _ = m.decode_texel_u8(x, y, mip, ChannelMask(1), &mut codes);
            }
            let req = SampleRequest {
                u: f32::NAN,
                v: 1e30,
                lod: -3.0,
                filter: Filter::Trilinear,
                precision: Precision::Integer,
                random: [0.5; 3],
                channels: ChannelMask::ALL,
            };
            let _ = m.sample(&req, &mut out);
        }
    }
    assert!(count > 0, "no regression inputs found under {}", root.display());
}
