//! Writer → parser round trips over many random materials, and the writer refusing what the
//! parser would refuse.

use nmat_core::internals::pack_codes;
use nmat_core::{
    Argument, ChannelMask, Container, Error, Field, LatentGrid, Material, MaterialSpec, SectionKind,
};
use nmat_tests::generate::{
    FixtureConfig, Layout, Rng, generate, random_config, terms_in_any_order, wide_cells,
};
use nmat_tests::generate_jpeg::DcJpegMaterial;
use nmat_tests::{files, reference};

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
        // Constant channels (one value, nothing decoded): one in five materials has one, and
        // one in fifty has nothing else.
        let constant = match seed % 50 {
            7 => spec.channels.len(),
            _ if seed % 5 == 1 => 1,
            _ => 0,
        };
        for c in &mut spec.channels[..constant] {
            c.range_max = c.range_min;
        }
        let bytes = spec.to_bytes().unwrap_or_else(|e| panic!("seed {seed}: {e}\n{cfg:?}"));
        let m = Container::parse(&bytes).unwrap();
        assert_eq!(m.to_spec().as_ref(), Some(&spec), "seed {seed}");
        assert_says_what_its_file_holds(&m, &spec, &bytes, seed);
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

/// What a parsed material says of itself — its network's input format, its sections, its
/// informative channels and BPPC — against the spec it was written from and the section table
/// read from its bytes (FORMAT.md §1.2, §3, §5.3).
fn assert_says_what_its_file_holds(m: &Material<'_>, spec: &MaterialSpec, bytes: &[u8], seed: u64) {
    let mlp = m.neural().expect("a neural material").mlp();
    let s = &spec.mlp;
    assert_eq!(
        (mlp.input_frac_bits(), mlp.pe_frequencies(), mlp.lod_input(), mlp.lod_code()),
        (s.input_frac_bits, s.pe_frequencies, s.lod_input != 0, s.lod_input),
        "seed {seed}: the network's input format"
    );
    assert_eq!(m.file_len(), bytes.len(), "seed {seed}");
    for kind in 1..=4 {
        let len = files::section(bytes, kind).1;
        assert_eq!(m.section_len(SectionKind(kind)), Some(len), "seed {seed}: section {kind}");
    }
    assert_eq!(m.section_len(SectionKind::JPEG), None, "seed {seed}: a neural material");
    for (kind, data) in &spec.optional_sections {
        assert_eq!(m.optional_section(SectionKind(*kind)), Some(&data[..]), "seed {seed}");
        assert_eq!(m.section_len(SectionKind(*kind)), Some(data.len()), "seed {seed}");
    }
    let absent = SectionKind(0x7E57_0000);
    assert_eq!((m.optional_section(absent), m.section_len(absent)), (None, None), "seed {seed}");
    // BPPC counts the channels that carry information, at least one (docs/ENCODING.md, "Quality
    // measures").
    let informative = spec.channels.iter().filter(|c| c.range_min != c.range_max).count().max(1);
    assert_eq!(m.informative_channels(), informative, "seed {seed}");
    let texels = f64::from(spec.width) * f64::from(spec.height) * informative as f64;
    assert_eq!(m.bppc(), bytes.len() as f64 * 8.0 / texels, "seed {seed}");
    assert_eq!(m.bppc_of(3), 24.0 / texels, "seed {seed}: a packed file of 3 bytes");
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

    // Vectors longer than the record that holds them, named with their length and the limit.
    let too_long = |e: Result<Vec<u8>, Error>, value, limit| {
        assert_eq!(e, Err(Error::BadArgument { argument: Argument::Spec, value, limit }));
    };
    let mut s = base.clone();
    s.channels[0].name = "a-name-longer-than-16".into();
    too_long(s.to_bytes(), 21, 16);
    s.mip_to_level = vec![0; 17];
    s.channels[0].name = "sixteen-bytes-ok".into();
    too_long(s.to_bytes(), 17, 16);
    // At the limits: a name of 16 bytes (no NUL) and a table of all 16 mips, zeros past the chain.
    s.mip_to_level = vec![0; 16];
    let bytes = s.to_bytes().unwrap();
    let back = Container::parse(&bytes).unwrap().to_spec().unwrap();
    assert_eq!(back.channels[0].name, "sixteen-bytes-ok");
    assert_eq!(back.mip_to_level, vec![0; usize::from(s.mip_count)]);

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

/// A parsed grid reads back the codes the writer was given, cell by cell and channel by channel
/// (channel fastest, then x, then y, FORMAT.md §4), and their values `offset + code · step`:
/// `code`, `value` and `cell_values` (which reads a cell's codes in one 64-bit window where they
/// fit, latent by latent where not), on random layouts and on cells of up to 128 bits
/// (`wide_cells`). Past the grid (a cell or channel index out of range) codes read as 0.
#[test]
fn grids_read_back_their_codes_and_values() {
    let configs = (0..40).map(random_config).chain([wide_cells(), terms_in_any_order()]);
    for cfg in configs {
        let spec = generate(&cfg);
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let grids = m.neural().expect("a neural material").grids();
        for (g, (grid, want)) in grids.iter().zip(&spec.grids).enumerate() {
            let (w, h) = (u32::from(want.width), u32::from(want.height));
            let channels = usize::from(want.channels);
            let at = |x: u32, y: u32| format!("seed {} grid {g} cell ({x}, {y})", cfg.seed);
            let mut values = [i32::MIN; 17];
            for y in 0..h {
                for x in 0..w {
                    grid.cell_values(x, y, &mut values);
                    let codes = &want.codes[(y * w + x) as usize * channels..][..channels];
                    let cells = codes.iter().zip(&want.quantization).zip(&values);
                    for (c, ((&code, &(offset, step)), &got)) in cells.enumerate() {
                        let value = i32::from(offset) + i32::from(code) * i32::from(step);
                        assert_eq!(grid.code(x, y, c), code, "{} channel {c}", at(x, y));
                        assert_eq!(grid.value(x, y, c), value, "{} channel {c}", at(x, y));
                        assert_eq!(got, value, "{} channel {c}: cell_values", at(x, y));
                    }
                    // Entries past the grid's channels are left alone.
                    assert!(values[channels..].iter().all(|&v| v == i32::MIN), "{}", at(x, y));
                }
            }
            for (x, y) in [(w, 0), (0, h), (w, h), (u32::MAX, u32::MAX)] {
                grid.cell_values(x, y, &mut values);
                for (c, (&got, &(offset, _))) in values.iter().zip(&want.quantization).enumerate() {
                    assert_eq!(grid.code(x, y, c), 0, "{}", at(x, y));
                    assert_eq!(got, i32::from(offset), "{}", at(x, y));
                }
            }
            assert_eq!(grid.code(0, 0, channels), 0, "seed {} grid {g}", cfg.seed);
        }
    }
}

/// A parsed network's layers read back what the writer was given: widths, the Q-format each
/// reads (the previous layer's output format, the input vector's for the first) and writes, the
/// activation, every weight, scale and bias, and the float decoder's weights and biases as
/// FORMAT.md §6.8 derives them (`w · scale`; `bias · scale · 2^−in` in f64, rounded once).
#[test]
fn layers_read_back_their_specification() {
    for seed in 0..40 {
        let spec = generate(&random_config(seed));
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let layers = m.neural().expect("a neural material").mlp().layers();
        assert_eq!(layers.len(), spec.mlp.layers.len(), "seed {seed}");
        let mut in_frac = spec.mlp.input_frac_bits;
        for (l, (layer, want)) in layers.iter().zip(&spec.mlp.layers).enumerate() {
            let at = format!("seed {seed} layer {l}");
            assert_eq!(
                (layer.inputs(), layer.outputs()),
                (want.inputs.into(), want.outputs.into())
            );
            assert_eq!(layer.in_frac_bits(), in_frac, "{at}");
            assert_eq!(layer.out_frac_bits(), want.out_frac_bits, "{at}");
            assert_eq!(layer.activation(), want.activation, "{at}");
            let lsb = 1.0 / f64::from(1u32 << in_frac);
            for o in 0..layer.outputs() {
                let scale = want.scales[o];
                assert_eq!(layer.scale(o).to_bits(), scale.to_bits(), "{at} row {o}");
                assert_eq!(layer.bias(o), want.bias[o], "{at} row {o}");
                let bias = (f64::from(want.bias[o]) * f64::from(scale) * lsb) as f32;
                assert_eq!(layer.float_bias(o).to_bits(), bias.to_bits(), "{at} row {o}");
                for i in 0..layer.inputs() {
                    let w = want.weights_i8[o * layer.inputs() + i];
                    assert_eq!(layer.weight_i8(o, i), w, "{at} weight ({o}, {i})");
                    let float = f32::from(w) * scale;
                    assert_eq!(layer.float_weight(o, i).to_bits(), float.to_bits(), "{at}");
                }
            }
            in_frac = want.out_frac_bits;
        }
    }
}

#[test]
fn a_jpeg_material_says_which_sections_it_has() {
    let mut spec = DcJpegMaterial::new(3).spec;
    spec.optional_sections = vec![(0x7E57_0001, vec![7; 5]), (0x7E57_0002, vec![])];
    // A constant channel (the height map's) leaves 7 informative channels of 8.
    spec.channels[7].range_max = spec.channels[7].range_min;
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    assert_eq!(m.file_len(), bytes.len());
    // MATERIAL and JPEG, none of a neural material's (FORMAT.md §11).
    for kind in 1..=5 {
        let len = [1, 5].contains(&kind).then(|| files::section(&bytes, kind).1);
        assert_eq!(m.section_len(SectionKind(kind)), len, "section {kind}");
    }
    assert_eq!(m.optional_section(SectionKind(0x7E57_0001)), Some(&[7u8; 5][..]));
    assert_eq!(m.section_len(SectionKind(0x7E57_0002)), Some(0));
    assert_eq!(m.informative_channels(), 7);
    assert_eq!(m.bppc(), bytes.len() as f64 * 8.0 / (70.0 * 37.0 * 7.0));
    assert!(m.to_spec().is_none(), "a JPEG material has no neural spec");
}

/// An MCU more than 65535 bits after the first of its index group cannot be indexed (FORMAT.md
/// §11.2: 16-bit offsets within a group of 9): the writer names the MCU, the offset and the limit.
#[test]
fn the_jpeg_writer_names_an_mcu_too_far_from_its_group_s_first() {
    let mut spec = DcJpegMaterial::new(1).spec;
    let stream = spec.streams.iter_mut().find(|s| s.mcu_bits.len() >= 14).unwrap();
    // MCU 13: the fifth of the second group.
    stream.mcu_bits[13] = stream.mcu_bits[9] + 65536;
    assert_eq!(
        spec.to_bytes(),
        Err(Error::LimitExceeded {
            field: Field::JpegIndex,
            index: 13,
            value: 65536,
            limit: 65535
        })
    );
}
