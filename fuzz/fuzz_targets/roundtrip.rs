//! A structured material (every layout knob the generator has, chosen by the fuzzer) → writer →
//! parser: the spec must come back unchanged and decode like the reference decoder.
#![no_main]
use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use nmat_core::{AddressMode, ChannelMask, Container};
use nmat_tests::generate::{fitting_lod_code, generate, FixtureConfig, Layout};

#[derive(Arbitrary, Debug)]
struct Shape {
    seed: u64,
    width: u8,
    height: u8,
    mips: u8,
    channels: u8,
    nbc: bool,
    c_a: u8,
    c_b: u8,
    bits_a: u8,
    bits_b: u8,
    nbc_levels: [u8; 4],
    clamp: bool,
    hidden: Vec<u8>,
    pe: u8,
    lod: u8,
    frac: [u8; 3],
    probes: Vec<(i16, i16, u8)>,
}

// Writer, parser, checksum, `to_spec` and the decoders each cost about one instrumented step per
// latent or weight, and the fuzzer keeps (and mutates most) the inputs of the largest loops: the
// common case is small, and one long side and one wide layer at most.

/// A side of the material: 1..=16 for 7 byte values of 8 (five mips: three NTC levels, four NBC
/// levels with the coarsest covering two mips); when `long` is allowed, 18..=80 for the rest
/// (seven mips, a fourth NTC level).
fn side(b: u8, long: bool) -> u32 {
    if b >= 224 && long { u32::from(b - 224) * 2 + 18 } else { u32::from(b % 16) + 1 }
}

/// Up to 3 hidden layers: 1..=8 wide for 7 byte values of 8; the first layer whose byte is one
/// of the others gets an even width up to 64 (one to four blocks of 16 rows in the packed layout).
fn hidden_widths(bytes: &[u8]) -> Vec<u16> {
    let mut wide_left = true;
    let mut width = |h: u8| match h {
        224.. if std::mem::take(&mut wide_left) => u16::from(h - 224) * 2 + 2,
        _ => u16::from(h % 8) + 1,
    };
    bytes.iter().take(3).map(|&h| width(h)).collect()
}

fuzz_target!(|s: Shape| {
    let width = side(s.width, true);
    let height = side(s.height, width <= 16);
    let full = 32 - width.max(height).leading_zeros();
    let input_frac_bits = 6 + s.frac[0] % 9;
    let layout = if s.nbc {
        let levels = usize::from(s.nbc_levels[0] % 4) + 1;
        Layout::Nbc { channels: s.c_a % 16 + 1, bits_coarse_to_fine: s.nbc_levels[..levels].iter().map(|b| b % 8 + 1).collect() }
    } else {
        Layout::Ntc { hi_channels: s.c_a % 12 + 1, lo_channels: s.c_b % 12 + 1, hi_bits: s.bits_a % 8 + 1, lo_bits: s.bits_b % 8 + 1 }
    };
    let cfg = FixtureConfig {
        name: "fuzz",
        seed: s.seed,
        width,
        height,
        mip_count: (u32::from(s.mips) % full + 1) as u8,
        channels: s.channels % 16 + 1,
        layout,
        address_mode: if s.clamp { AddressMode::Clamp } else { AddressMode::Wrap },
        hidden: hidden_widths(&s.hidden),
        pe_frequencies: s.pe % (input_frac_bits - 2).min(5),
        lod_input: fitting_lod_code(s.lod % 6, input_frac_bits),
        input_frac_bits,
        hidden_frac_bits: 8 + s.frac[1] % 6,
        output_frac_bits: 8 + s.frac[2] % 7,
        ntc_hi_bilinear: !s.nbc && s.seed % 2 == 1,
    };
    let spec = generate(&cfg);
    let bytes = spec.to_bytes().expect("the generator makes valid materials");
    let m = Container::parse(&bytes).expect("written files parse");
    assert_eq!(m.to_spec().as_ref(), Some(&spec));
    let mut out = [0u8; 16];
    for &(x, y, mip) in s.probes.iter().take(4) {
        let (x, y, mip) = (i64::from(x), i64::from(y), u32::from(mip));
        let n = m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut out).expect("valid request");
        assert_eq!(out[..n].to_vec(), nmat_tests::reference::decode_u8(&spec, x, y, mip));
    }
});
