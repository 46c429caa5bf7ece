//! Writer → parser round trips over many random materials, and the writer refusing what the
//! parser would refuse.

use nmat_core::internals::pack_codes;
use nmat_core::{Argument, ChannelMask, Container, Error, Field, LatentGrid};
use nmat_tests::generate::{FixtureConfig, Layout, Rng, generate, random_config};
use nmat_tests::reference;

#[test]
fn random_materials_round_trip_exactly() {
    for seed in 0..300 {
        let cfg = random_config(seed);
        let mut spec = generate(&cfg);
        if seed % 3 == 0 {
            // Optional sections survive the round trip and do not disturb decoding.
            spec.optional_sections
                .push((0x1000 + seed as u32, vec![seed as u8; seed as usize % 9]));
        }
        let bytes = spec.to_bytes().unwrap_or_else(|e| panic!("seed {seed}: {e}\n{cfg:?}"));
        let m = Container::parse(&bytes).unwrap();
        assert_eq!(m.to_spec().as_ref(), Some(&spec), "seed {seed}");
        let back = m.to_spec().expect("a neural material").to_bytes().unwrap();
        assert_eq!(back, bytes, "seed {seed}: re-serialization differs");
        // And the decoders agree with the reference on a few texels of every mip.
        let mut out = [0u8; 16];
        for mip in 0..m.mip_count() {
            for (x, y) in [(0, 0), (-1, 3), (i64::from(cfg.width) / 2, i64::from(cfg.height) - 1)] {
                let n = m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut out).unwrap();
                assert_eq!(
                    out[..n].to_vec(),
                    reference::decode_u8(&spec, x, y, mip),
                    "seed {seed}"
                );
            }
        }
    }
}

#[test]
fn packing_round_trips_at_every_bit_depth() {
    let mut r = Rng::new(99);
    for bits in 1..=8u8 {
        for len in [1usize, 2, 31, 32, 33, 95, 257] {
            let codes: Vec<u8> = (0..len).map(|_| r.range(0, (1 << bits) - 1) as u8).collect();
            let packed = pack_codes(&codes, bits);
            assert_eq!(packed.len(), (len * usize::from(bits)).div_ceil(32) * 4);
            // Read back through the parser's view by building a one-row grid.
            let mut spec = generate(&FixtureConfig {
                layout: Layout::Ntc { hi_channels: 1, lo_channels: 1, hi_bits: bits, lo_bits: 1 },
                ..FixtureConfig::ntc("pack", 1, 4, 4, 1)
            });
            let g = &mut spec.grids[0];
            (g.width, g.height, g.codes) = (len as u16, 1, codes.clone());
            let bytes = spec.to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            let grid: &LatentGrid<'_> = &m.neural().expect("a neural material").grids()[0];
            assert_eq!(grid.packed_data(), &packed[..]);
            let back: Vec<u8> = (0..len as u32).map(|x| grid.code(x, 0, 0)).collect();
            assert_eq!(back, codes, "bits {bits} len {len}");
        }
    }
}

#[test]
fn writer_rejects_inconsistent_specs_with_named_errors() {
    let base = generate(&FixtureConfig::ntc("w", 3, 20, 10, 3));
    let spec_error = |e: Result<Vec<u8>, Error>| {
        matches!(e, Err(Error::BadArgument { argument: Argument::Spec, .. }))
    };

    let mut s = base.clone();
    s.grids[0].codes.pop();
    assert!(spec_error(s.to_bytes()));

    let mut s = base.clone();
    s.mlp.layers[0].bias.push(0);
    assert!(spec_error(s.to_bytes()));

    let mut s = base.clone();
    s.channels[0].name = "a-name-longer-than-16".into();
    assert!(spec_error(s.to_bytes()));

    let mut s = base.clone();
    s.channels[1].name = String::new();
    assert!(matches!(
        s.to_bytes(),
        Err(Error::Malformed { field: Field::ChannelName, index: 1, .. })
    ));

    let mut s = base.clone();
    s.channels[2].range_min = 2.0;
    assert!(matches!(
        s.to_bytes(),
        Err(Error::Malformed { field: Field::ChannelRange, index: 2, .. })
    ));

    let mut s = base.clone();
    s.mip_count = 9; // 20×10 has 5 mips
    assert!(matches!(s.to_bytes(), Err(Error::Malformed { field: Field::MipCount, .. })));

    let mut s = base.clone();
    s.mip_to_level[1] = 40;
    assert!(matches!(
        s.to_bytes(),
        Err(Error::Malformed { field: Field::MipToLevel, index: 1, .. })
    ));

    let mut s = base.clone();
    s.levels[0].terms[0].grids = vec![0, 1];
    assert!(matches!(s.to_bytes(), Err(Error::Malformed { field: Field::TermChainLength, .. })));

    let mut s = base.clone();
    s.levels[0].terms[1].grids = vec![17];
    assert!(matches!(s.to_bytes(), Err(Error::Malformed { field: Field::TermGrid, .. })));

    let mut s = base.clone();
    s.mlp.pe_frequencies += 1; // the level no longer feeds the MLP's input width
    assert!(matches!(s.to_bytes(), Err(Error::Malformed { field: Field::LevelFeatureWidth, .. })));

    let mut s = base.clone();
    s.mlp.input_frac_bits = 3;
    assert!(matches!(s.to_bytes(), Err(Error::Malformed { field: Field::InputFracBits, .. })));

    let mut s = base.clone();
    s.mlp.layers.last_mut().unwrap().outputs = 2;
    assert!(
        spec_error(s.to_bytes())
            || matches!(s.to_bytes(), Err(Error::Malformed { field: Field::LayerOutputs, .. }))
    );

    let mut s = base.clone();
    s.width = 16385;
    assert!(matches!(
        s.to_bytes(),
        Err(Error::LimitExceeded { field: Field::Width, value: 16385, limit: 16384, .. })
    ));

    let mut s = base;
    s.grids[0].bits = 9;
    assert!(matches!(s.to_bytes(), Err(Error::Malformed { field: Field::GridBits, .. })));
}
