//! Parse fuzzer-chosen bytes (checksum not verified), then decode texels and samples at
//! fuzzer-chosen coordinates, mips, LODs, filters and channel masks through both decoders; the
//! integer decoder must equal the independent reference decoder on every accepted neural file
//! (the reference does not cover JPEG materials yet), and the prepared `Decoder` (the machine's
//! fastest kernel or the scalar one, as the input chooses) must equal `Material` for both codecs.
#![no_main]
use arbitrary::{Arbitrary, Unstructured};
use libfuzzer_sys::fuzz_target;
use nmat_core::{ChannelMask, Container, Decoder, Filter, Kernel, ParseOptions, Precision, SampleRequest};

#[derive(Arbitrary, Debug)]
struct Request {
    x: i64,
    y: i64,
    mip: u32,
    mask: u16,
    u: f32,
    v: f32,
    lod: f32,
    filter: u8,
    random: [f32; 3],
}

fuzz_target!(|data: &[u8]| {
    // The file is the input up to its declared length; the bytes after it choose the requests.
    // So a plain .nmat (the seed corpus) is a valid input as it is.
    let declared = data.get(12..16).map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
    let split = if (32..=data.len()).contains(&declared) { declared } else { data.len() };
    let (file, controls) = data.split_at(split);
    let mut u = Unstructured::new(controls);
    // One prepared decoder per input, the machine's fastest kernel or the scalar one (preparing
    // one took a tenth of an execution; the fuzzer varies the choice from input to input).
    let scalar = u.arbitrary::<bool>().unwrap_or(false);
    // Two requests at most: each costs dozens of texel decodes (a whole MCU each for a JPEG
    // material), and the fuzzer varies them from input to input.
    let mut requests: Vec<Request> = (0..2).map_while(|_| Request::arbitrary(&mut u).ok()).collect();
    if requests.is_empty() {
        let corner = |x, y, mip, lod| Request { x, y, mip, mask: 0xFFFF, u: 0.3, v: 0.7, lod, filter: 2, random: [0.5; 3] };
        requests.extend([corner(0, 0, 0, 0.0), corner(-1, 5, 1, 1.5), corner(i64::MAX, i64::MIN, u32::MAX, 99.0)]);
    }
    let Ok(m) = Container::parse_with(file, ParseOptions { verify_checksum: false }) else { return };
    let spec = m.to_spec();
    let decoders = [if scalar { Decoder::with_kernel(&m, Kernel::Scalar).expect("always available") } else { Decoder::new(&m) }];
    for r in &requests {
        let mask = ChannelMask(r.mask);
        // `Material`'s decodes, once: each decoder below must equal them.
        let (mut f, mut c8, mut c16) = ([0f32; 16], [0u8; 16], [0u16; 16]);
        let float = m.decode_texel(r.x, r.y, r.mip, mask, &mut f);
        let codes16 = m.decode_texel_u16(r.x, r.y, r.mip, mask, &mut c16);
        if let (Ok(n), Some(spec)) = (m.decode_texel_u8(r.x, r.y, r.mip, ChannelMask::ALL, &mut c8), &spec) {
            assert_eq!(c8[..n].to_vec(), nmat_tests::reference::decode_u8(spec, r.x, r.y, r.mip));
        }
        // The 6 texels from x, decoded one by one when a span first succeeds.
        let mut singles: Option<[[u8; 16]; 6]> = None;
        for d in &decoders {
            let (mut g, mut d16) = ([0f32; 16], [0u16; 16]);
            if let (Ok(n), Ok(k)) = (&float, d.decode_texel(&m, r.x, r.y, r.mip, mask, &mut g)) {
                assert_eq!(*n, k);
                assert_eq!(f[..k].iter().map(|v| v.to_bits()).collect::<Vec<_>>(), g[..k].iter().map(|v| v.to_bits()).collect::<Vec<_>>());
            }
            if let (Ok(n), Ok(_)) = (&codes16, d.decode_texel_u16(&m, r.x, r.y, r.mip, mask, &mut d16)) {
                assert_eq!(c16[..*n], d16[..*n]);
            }
            // A span of 6 texels from x equals 6 single decodes.
            let mut span = [0u8; 6 * 16];
            if let Ok(total) = d.decode_span_u8(&m, r.x, r.y, r.mip, 6, mask, &mut span) {
                let n = total / 6;
                let singles = singles.get_or_insert_with(|| {
                    let mut all = [[0u8; 16]; 6];
                    for (i, one) in all.iter_mut().enumerate() {
                        m.decode_texel_u8(r.x.wrapping_add(i as i64), r.y, r.mip, mask, one).expect("span succeeded");
                    }
                    all
                });
                for (i, one) in singles.iter().enumerate() {
                    assert_eq!(span[i * n..(i + 1) * n], one[..n]);
                }
            }
        }
        let filter = [Filter::Nearest, Filter::Bilinear, Filter::Trilinear, Filter::Stochastic][usize::from(r.filter % 4)];
        for precision in [Precision::Float, Precision::Integer] {
            let req = SampleRequest { u: r.u, v: r.v, lod: r.lod, filter, precision, random: r.random, channels: mask };
            if m.sample(&req, &mut f).is_ok() {
                assert!(f.iter().all(|v| v.is_finite()));
            }
        }
    }
});
