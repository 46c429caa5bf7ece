//! The core's BC blocks against an independent decoder (`bcdec_rs`, a port of the widely used
//! `bcdec`): every block — any bytes, and every block the encoders write for real images —
//! decodes to the same values with both.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::bc::{
    ALL_VALID, decode_bc1, decode_bc4, decode_bc5, decode_bc7, encode_bc1, encode_bc4, encode_bc5,
    encode_bc7, valid_mask,
};

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

fn peer_bc1(block: &[u8; 8]) -> [[u8; 4]; 16] {
    let mut rgba = [0u8; 64];
    bcdec_rs::bc1(block, &mut rgba, 16);
    std::array::from_fn(|i| [rgba[4 * i], rgba[4 * i + 1], rgba[4 * i + 2], rgba[4 * i + 3]])
}

fn peer_bc4(block: &[u8; 8]) -> [u8; 16] {
    let mut out = [0u8; 16];
    bcdec_rs::bc4(block, &mut out, 4, false);
    out
}

fn peer_bc5(block: &[u8; 16]) -> ([u8; 16], [u8; 16]) {
    let mut rg = [0u8; 32];
    bcdec_rs::bc5(block, &mut rg, 8, false);
    (std::array::from_fn(|i| rg[2 * i]), std::array::from_fn(|i| rg[2 * i + 1]))
}

fn peer_bc7(block: &[u8; 16]) -> [[u8; 4]; 16] {
    let mut rgba = [0u8; 64];
    bcdec_rs::bc7(block, &mut rgba, 16);
    std::array::from_fn(|i| [rgba[4 * i], rgba[4 * i + 1], rgba[4 * i + 2], rgba[4 * i + 3]])
}

/// Random bytes as blocks, and every endpoint pair of BC4 (both palette modes): the same values.
#[test]
fn any_block_decodes_like_bcdec() {
    let mut rng = Rng(0x00C0_FFEE);
    for _ in 0..200_000 {
        let a = rng.next().to_le_bytes();
        let b = rng.next().to_le_bytes();
        assert_eq!(decode_bc1(&a), peer_bc1(&a), "BC1 {a:02x?}");
        assert_eq!(decode_bc4(&a), peer_bc4(&a), "BC4 {a:02x?}");
        let mut ab = [0u8; 16];
        ab[..8].copy_from_slice(&a);
        ab[8..].copy_from_slice(&b);
        assert_eq!(decode_bc5(&ab), peer_bc5(&ab), "BC5 {ab:02x?}");
        // Every BC7 mode equally often (the first byte's lowest set bit), and the reserved one.
        let mut bc7 = ab;
        let mode = rng.next() % 9;
        bc7[0] = if mode == 8 { 0 } else { (bc7[0] | 1) << mode };
        assert_eq!(decode_bc7(&bc7), peer_bc7(&bc7), "BC7 {bc7:02x?}");
    }
    for a0 in 0..=255u8 {
        for a1 in 0..=255u8 {
            let block = [a0, a1, 0x88, 0xC6, 0xFA, 0x88, 0xC6, 0xFA];
            assert_eq!(decode_bc4(&block), peer_bc4(&block), "BC4 endpoints {a0} {a1}");
        }
    }
}

/// A procedural image with gradients, edges and noise, 37×29 (edge blocks partly outside), as
/// RGB; its blocks encoded by the core decode the same with both decoders, and the pixels
/// outside the image do not matter.
#[test]
fn encoded_images_decode_like_bcdec() {
    let (w, h) = (37u32, 29u32);
    let mut rng = Rng(17);
    let mut modes = [0usize; 8];
    let pixel = |x: u32, y: u32, rng: &mut Rng| -> [u8; 3] {
        let n = (rng.next() % 19) as i32 - 9;
        let edge = if (x + 2 * y) % 23 < 11 { 90 } else { 0 };
        let c = |v: i32| v.clamp(0, 255) as u8;
        [c(x as i32 * 6 + edge + n), c(200 - y as i32 * 5 + n), c(((x * y) % 256) as i32 / 2 + n)]
    };
    let image: Vec<[u8; 3]> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| pixel(x, y, &mut rng))
        .collect();
    for by in 0..h.div_ceil(4) {
        for bx in 0..w.div_ceil(4) {
            let valid = valid_mask(bx, by, w, h);
            let at = |i: usize| {
                let (x, y) = (4 * bx + i as u32 % 4, 4 * by + i as u32 / 4);
                // Past the edge: something arbitrary (the encoders must ignore it).
                image
                    .get((y * w + x) as usize)
                    .filter(|_| x < w && y < h)
                    .copied()
                    .unwrap_or([7, 7, 7])
            };
            let rgb: [[u8; 3]; 16] = std::array::from_fn(at);
            let (r, g): ([u8; 16], [u8; 16]) =
                (std::array::from_fn(|i| rgb[i][0]), std::array::from_fn(|i| rgb[i][1]));
            let b1 = encode_bc1(&rgb, valid);
            assert_eq!(decode_bc1(&b1), peer_bc1(&b1));
            let b4 = encode_bc4(&r, valid);
            assert_eq!(decode_bc4(&b4), peer_bc4(&b4));
            let b5 = encode_bc5(&r, &g, valid);
            assert_eq!(decode_bc5(&b5), peer_bc5(&b5));
            // BC7: RGB, and RGBA with an alpha from the red and blue channels.
            let rgba: [[u8; 4]; 16] = std::array::from_fn(|i| {
                let [r, g, b] = rgb[i];
                [r, g, b, if (bx + by) % 3 == 0 { 255 } else { r / 2 + b / 3 }]
            });
            let b7 = encode_bc7(&rgba, valid, false);
            assert_eq!(decode_bc7(&b7), peer_bc7(&b7));
            assert!(decode_bc7(&b7).iter().all(|p| p[3] == 255), "an RGB block is opaque");
            let b7a = encode_bc7(&rgba, valid, true);
            assert_eq!(decode_bc7(&b7a), peer_bc7(&b7a));
            modes[usize::from(b7[0].trailing_zeros() as u8)] += 1;
            modes[usize::from(b7a[0].trailing_zeros() as u8)] += 1;
            if valid != ALL_VALID {
                let other: [[u8; 3]; 16] =
                    std::array::from_fn(
                        |i| {
                            if (valid >> i) & 1 != 0 { rgb[i] } else { [250, 3, 128] }
                        },
                    );
                assert_eq!(encode_bc1(&other, valid), b1, "block ({bx}, {by})");
                let other4: [[u8; 4]; 16] =
                    std::array::from_fn(|i| if (valid >> i) & 1 != 0 { rgba[i] } else { [9; 4] });
                assert_eq!(encode_bc7(&other4, valid, true), b7a, "block ({bx}, {by})");
            }
        }
    }
    // The image exercises every mode the BC7 encoder writes: 0–6 opaque, 5 or 6 with alpha.
    assert!(modes[..7].iter().all(|&n| n > 0), "modes {modes:?}");
}

/// The committed fixture files (odd sizes, 1×1, strips, 16 channels), sorted.
fn fixture_files() -> Vec<std::path::PathBuf> {
    let dir = nmat_tests::fixtures_dir();
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "nmat"))
        // A packed twin (`NAME.packed.nmat`) unpacks to its fixture byte for byte.
        .filter(|p| !p.to_string_lossy().ends_with(".packed.nmat"))
        .collect();
    files.sort();
    assert!(files.len() >= 5, "fixtures in {}", dir.display());
    files
}

/// Every fixture (odd sizes, 1×1, strips, 16 channels): each texture of the default layout,
/// transcoded mip by mip through `Decoder::transcode_blocks` with a padded row pitch, equals
/// blocks built texel by texel from `Material::decode_texel_u8` and encoded one by one; and the
/// same with every kernel the CPU has, and when the mip is split into regions.
#[test]
fn transcoded_mips_equal_blocks_of_decoded_texels() {
    use nmat_core::bc::{BcFormat, default_layout, encode_block, layout_with};
    use nmat_core::{BlockRegion, ChannelMask, Container, Decoder, Kernel};
    let files = fixture_files();
    for file in files {
        let bytes = std::fs::read(&file).unwrap();
        let m = Container::parse(&bytes).unwrap();
        let layout = default_layout(&m);
        // Every channel once, but a normal map's Z.
        let normal_z = m
            .channels()
            .iter()
            .filter(|c| c.semantic == nmat_core::Semantic::NORMAL && c.component == 2)
            .count();
        let covered = layout.iter().map(|t| t.channel_list().len()).sum::<usize>();
        assert_eq!(covered + normal_z, m.channel_count(), "{}", file.display());
        // And every map in BC7 (RGB, or RGBA for maps of four channels).
        let bc7 = layout_with(&m, |_| Some(BcFormat::Bc7Rgb));
        for texture in layout.iter().chain(&bc7) {
            for mip in 0..m.mip_count() {
                let (w, h) = m.mip_size(mip);
                let region = BlockRegion::mip(&m, mip);
                let bb = texture.format.block_bytes();
                // The reference: texel by texel, block by block.
                let mut want = Vec::new();
                for by in 0..region.height {
                    for bx in 0..region.width {
                        let valid = valid_mask(bx, by, w, h);
                        let px: [[u8; 4]; 16] = std::array::from_fn(|i| {
                            let (x, y) = (4 * bx + i as u32 % 4, 4 * by + i as u32 / 4);
                            if x >= w || y >= h {
                                return [0; 4];
                            }
                            let mut all = [0u8; 16];
                            let n = m
                                .decode_texel_u8(
                                    x.into(),
                                    y.into(),
                                    mip,
                                    ChannelMask::ALL,
                                    &mut all,
                                )
                                .unwrap();
                            assert_eq!(n, m.channel_count());
                            let c = |k: usize| {
                                texture.channel_list().get(k).map_or(0, |&c| all[usize::from(c)])
                            };
                            [c(0), c(1), c(2), c(3)]
                        });
                        let mut block = [0u8; 16];
                        encode_block(texture.format, &px, valid, &mut block);
                        want.extend(&block[..bb]);
                    }
                }
                let row = region.width as usize * bb;
                let pitch = row + 5;
                let at = format!("{} {texture:?} mip {mip}", file.display());
                for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
                    let d = Decoder::with_kernel(&m, kernel).unwrap();
                    let mut out = vec![0xA5u8; pitch * region.height as usize];
                    d.transcode_blocks(&m, texture, mip, region, &mut out, pitch).unwrap();
                    let got: Vec<u8> = out.chunks(pitch).flat_map(|r| r[..row].to_vec()).collect();
                    assert_eq!(got, want, "{kernel:?} {at}");
                    assert!(out.chunks(pitch).all(|r| r[row..].iter().all(|&b| b == 0xA5)));
                }
                // Split: the top block rows, then the rest in two column halves.
                let d = Decoder::new(&m);
                let mut split = vec![0u8; row * region.height as usize];
                let top = region.height / 2;
                let left = region.width / 2;
                let parts = [
                    BlockRegion { height: top, ..region },
                    BlockRegion { y: top, height: region.height - top, width: left, ..region },
                    BlockRegion {
                        y: top,
                        x: left,
                        height: region.height - top,
                        width: region.width - left,
                    },
                ];
                for p in parts {
                    let start = p.y as usize * row + p.x as usize * bb;
                    let end = split.len();
                    d.transcode_blocks(&m, texture, mip, p, &mut split[start..end], row).unwrap();
                }
                assert_eq!(split, want, "split {at}");
            }
        }
    }
}

/// Several textures in one pass (`Decoder::transcode_textures`: one decode of the union of their
/// channels) give each texture's bytes from `transcode_blocks` alone, on every fixture, mip and
/// kernel, with a different row pitch per target; a bad target makes the call write nothing.
#[test]
fn textures_in_one_pass_equal_each_texture_alone() {
    use nmat_core::bc::{BcFormat, layout_with};
    use nmat_core::{Argument, BcTarget, BlockRegion, Container, Decoder, Error, Kernel};
    let files = fixture_files();
    for file in files {
        let bytes = std::fs::read(&file).unwrap();
        let m = Container::parse(&bytes).unwrap();
        let mut textures = layout_with(&m, |_| None).to_vec();
        textures.extend(layout_with(&m, |map| (map.count >= 3).then_some(BcFormat::Bc7Rgb)));
        textures.extend(layout_with(&m, |_| Some(BcFormat::Bc4)));
        for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
            let d = Decoder::with_kernel(&m, kernel).unwrap();
            for mip in 0..m.mip_count() {
                let region = BlockRegion::mip(&m, mip);
                let pitch = |k: usize, t: &nmat_core::bc::BcTexture| {
                    region.width as usize * t.format.block_bytes() + 3 * k
                };
                let alone: Vec<Vec<u8>> = textures
                    .iter()
                    .enumerate()
                    .map(|(k, t)| {
                        let mut out = vec![0u8; pitch(k, t) * region.height as usize];
                        d.transcode_blocks(&m, t, mip, region, &mut out, pitch(k, t)).unwrap();
                        out
                    })
                    .collect();
                let mut outs: Vec<Vec<u8>> = alone.iter().map(|a| vec![0u8; a.len()]).collect();
                let mut targets: Vec<BcTarget<'_>> = textures
                    .iter()
                    .zip(&mut outs)
                    .enumerate()
                    .map(|(k, (t, out))| BcTarget { texture: *t, out, row_pitch: pitch(k, t) })
                    .collect();
                d.transcode_textures(&m, mip, region, &mut targets).unwrap();
                assert!(outs == alone, "{} {kernel:?} mip {mip}", file.display());
            }
        }
        // One target too short: an error naming the output, and no target is written.
        let d = Decoder::new(&m);
        let region = BlockRegion::mip(&m, 0);
        let mut outs: Vec<Vec<u8>> = textures
            .iter()
            .map(|t| {
                vec![0u8; region.width as usize * t.format.block_bytes() * region.height as usize]
            })
            .collect();
        outs.last_mut().unwrap().pop();
        let mut targets: Vec<BcTarget<'_>> = textures
            .iter()
            .zip(&mut outs)
            .map(|(t, out)| BcTarget {
                texture: *t,
                out,
                row_pitch: region.width as usize * t.format.block_bytes(),
            })
            .collect();
        let e = d.transcode_textures(&m, 0, region, &mut targets).unwrap_err();
        assert!(matches!(e, Error::BadArgument { argument: Argument::Output, .. }), "{e:?}");
        assert!(outs.iter().all(|o| o.iter().all(|&b| b == 0)), "{}", file.display());
    }
}

/// Bad arguments are typed errors naming the argument, and nothing is written.
#[test]
fn transcode_refuses_bad_arguments() {
    use nmat_core::bc::{BcFormat, BcTexture};
    use nmat_core::{Argument, BlockRegion, Container, Decoder, Error};
    let bytes = std::fs::read(nmat_tests::fixtures_dir().join("ntc_rgb_64.nmat")).unwrap();
    let m = Container::parse(&bytes).unwrap();
    let d = Decoder::new(&m);
    let t = BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2, 2], srgb: true };
    let all = BlockRegion::mip(&m, 0);
    // 64 × 64 texels, 7 mips: 16 × 16 blocks, the last mip's one block, none past the chain.
    let blocks = |mip| BlockRegion::mip(&m, mip);
    assert_eq!((all.x, all.y, all.width, all.height), (0, 0, 16, 16));
    assert_eq!((blocks(6).width, blocks(6).height, m.mip_count()), (1, 1, 7));
    assert_eq!((blocks(7).width, blocks(7).height), (0, 0), "a mip past the chain");
    let row = all.width as usize * 8;
    let mut out = vec![0u8; row * all.height as usize];
    let argument = |e: Error| match e {
        Error::BadArgument { argument, .. } => argument,
        other => panic!("not a bad argument: {other:?}"),
    };
    let e = d.transcode_blocks(&m, &t, m.mip_count(), all, &mut out, row).unwrap_err();
    assert_eq!(argument(e), Argument::Mip);
    let wide = BlockRegion { width: all.width + 1, ..all };
    assert_eq!(
        argument(d.transcode_blocks(&m, &t, 0, wide, &mut out, row).unwrap_err()),
        Argument::Region
    );
    let low = BlockRegion { y: 1, ..all };
    assert_eq!(
        argument(d.transcode_blocks(&m, &t, 0, low, &mut out, row).unwrap_err()),
        Argument::Region
    );
    assert_eq!(
        argument(d.transcode_blocks(&m, &t, 0, all, &mut out, row - 1).unwrap_err()),
        Argument::RowPitch
    );
    let short = out.len() - 1;
    assert_eq!(
        argument(d.transcode_blocks(&m, &t, 0, all, &mut out[..short], row).unwrap_err()),
        Argument::Output
    );
    let missing = BcTexture { channels: [0, 1, 3, 3], ..t };
    assert_eq!(
        argument(d.transcode_blocks(&m, &missing, 0, all, &mut out, row).unwrap_err()),
        Argument::Channels
    );
    let beyond = BcTexture { channels: [0, 1, 200, 0], ..t };
    assert_eq!(
        argument(d.transcode_blocks(&m, &beyond, 0, all, &mut out, row).unwrap_err()),
        Argument::Channels
    );
    assert!(out.iter().all(|&b| b == 0), "an error wrote output");
    let tiny = std::fs::read(nmat_tests::fixtures_dir().join("tiny_1x1.nmat")).unwrap();
    let other = Container::parse(&tiny).unwrap();
    let e =
        d.transcode_blocks(&other, &t, 0, BlockRegion::mip(&other, 0), &mut out, row).unwrap_err();
    assert_eq!(argument(e), Argument::Material);
}

/// A constant channel (range_min = range_max: nothing decoded) transcodes to its value's code in
/// the usual range of image files: 0.75 of an AO map is 191, a normal X of 0 (stored as
/// (n + 1)/2) is 128 — whatever the network outputs for it.
#[test]
fn constant_channels_transcode_to_their_value() {
    use nmat_core::bc::{BcFormat, BcTexture, decode_block};
    use nmat_core::{BlockRegion, Container, Decoder};
    use nmat_tests::generate::{FixtureConfig, generate};
    let mut spec = generate(&FixtureConfig::ntc("constants", 9, 20, 12, 10));
    let (normal_x, ao) = (3, 8);
    assert_eq!(spec.channels[normal_x].semantic, nmat_core::Semantic::NORMAL);
    assert_eq!(spec.channels[ao].semantic, nmat_core::Semantic::AMBIENT_OCCLUSION);
    for (c, v) in [(normal_x, 0.0), (ao, 0.75)] {
        spec.channels[c].range_min = v;
        spec.channels[c].range_max = v;
    }
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let texture = BcTexture {
        format: BcFormat::Bc5,
        channels: [normal_x as u8, ao as u8, 0, 0],
        srgb: false,
    };
    let d = Decoder::new(&m);
    let region = BlockRegion::mip(&m, 0);
    let row = region.width as usize * 16;
    let mut out = vec![0u8; row * region.height as usize];
    d.transcode_blocks(&m, &texture, 0, region, &mut out, row).unwrap();
    for block in out.chunks(16) {
        assert!(decode_block(BcFormat::Bc5, block).iter().all(|p| p[0] == 128 && p[1] == 191));
    }
    // The rule itself, by hand: X, Y and Z of a normal map in −1 … 1, anything else (a normal
    // map's fourth component too) in 0 … 1, clamped, rounded; a decoded channel has no code.
    use nmat_core::Semantic as S;
    for (semantic, component, value, code) in [
        (S::NORMAL, 0, 0.5, Some(191)),
        (S::NORMAL, 2, -1.0, Some(0)),
        (S::NORMAL, 3, 0.5, Some(128)),
        (S::NORMAL, 3, -0.5, Some(0)),
        (S::ALBEDO, 1, 2.0, Some(255)),
        (S::HEIGHT, 0, 0.2, Some(51)),
    ] {
        let channel = nmat_core::Channel {
            name: "c",
            semantic,
            component,
            color_space: nmat_core::ColorSpace::Linear,
            range_min: value,
            range_max: value,
        };
        assert_eq!(channel.constant_code(), code, "{semantic:?} {component} at {value}");
        let decoded = nmat_core::Channel { range_max: value + 1.0, ..channel };
        assert_eq!(decoded.constant_code(), None, "{semantic:?} {component} decoded");
    }
}

/// BC1's single-colour endpoints (the table `nmat-wgpu` embeds), found here by trying every pair:
/// for each 8-bit value, the pair `[a, b]` of 5- or 6-bit endpoints whose point — `a` expanded,
/// `round(a · 255 / max)`, where `a = b`, else the 1/3 point `round((2a + b) · 255 / (3 · max))`
/// — is nearest the value; on a tie the lower point, then `a = b`, then the smallest `a`, then
/// the smallest `b`.
#[test]
fn bc1_single_colour_endpoints_are_the_nearest_pairs() {
    use nmat_core::bc::bc1_single_colour_endpoints;
    for (k, max) in [(0usize, 31i64), (1, 63)] {
        let round_div = |n: i64, d: i64| (2 * n + d) / (2 * d);
        for value in 0..=255i64 {
            let mut best = None;
            for a in 0..=max {
                for b in 0..=max {
                    let point = if a == b {
                        round_div(a * 255, max)
                    } else {
                        round_div((2 * a + b) * 255, 3 * max)
                    };
                    let key = ((point - value).abs(), point, a != b, a, b);
                    if best.is_none_or(|k| key < k) {
                        best = Some(key);
                    }
                }
            }
            let (_, _, _, a, b) = best.unwrap();
            let got = bc1_single_colour_endpoints(value as u8)[k];
            assert_eq!(got, [a as u8, b as u8], "{max}: value {value}");
        }
    }
}
