//! A structured material (every layout knob the generator has, chosen by the fuzzer) → writer →
//! parser: the spec must come back unchanged and decode like the reference decoder.
#![no_main]
use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use nmat_core::{AddressMode, ChannelMask, Container};
use nmat_tests::generate::{generate, FixtureConfig, Layout};

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
    lod: bool,
    frac: [u8; 3],
    probes: Vec<(i16, i16, u8)>,
}

fuzz_target!(|s: Shape| {
    let (width, height) = (u32::from(s.width % 80) + 1, u32::from(s.height % 80) + 1);
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
        hidden: s.hidden.iter().take(3).map(|h| u16::from(h % 64) + 1).collect(),
        pe_frequencies: s.pe % (input_frac_bits - 2).min(5),
        lod_input: s.lod,
        input_frac_bits,
        hidden_frac_bits: 8 + s.frac[1] % 6,
        output_frac_bits: 8 + s.frac[2] % 7,
    };
    let spec = generate(&cfg);
    let bytes = spec.to_bytes().expect("the generator makes valid materials");
    let m = Container::parse(&bytes).expect("written files parse");
    assert_eq!(m.to_spec(), spec);
    let mut out = [0u8; 16];
    for &(x, y, mip) in s.probes.iter().take(8) {
        let (x, y, mip) = (i64::from(x), i64::from(y), u32::from(mip));
        let n = m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut out).expect("valid request");
        assert_eq!(out[..n].to_vec(), nmat_tests::reference::decode_u8(&spec, x, y, mip));
    }
});
