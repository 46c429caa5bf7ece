//! Indexed JPEG (docs/FORMAT.md §11) against an independent decoder: files made by the
//! `jpeg-encoder` crate, indexed by `nmat_encode::jpeg`, decoded texel by texel and row by row by
//! `nmat-core`, and compared with libjpeg-turbo's `djpeg -dct int -nosmooth` (the integer IDCT and
//! chroma replicated, not interpolated: what an MCU decoded on its own can give).
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use std::process::Command;

mod common;

use common::{MODES, jpeg, pattern};
use jpeg_encoder::{ColorType, Encoder, SamplingFactor};
use nmat_core::{ChannelMask, Container, Decoder};
use nmat_encode::jpeg::{JpegError, index_jpeg, material_from_jpeg};

/// `djpeg -dct int -nosmooth` of `file`: samples, or `None` without djpeg.
fn djpeg(file: &[u8]) -> Option<Vec<u8>> {
    djpeg_outcome(file).map(|r| r.unwrap_or_else(|e| panic!("djpeg failed: {e}")))
}

/// `djpeg -dct int -nosmooth` of `file`: its samples (also where it only warned, exit status 2),
/// or what it said when it refused the file; `None` without djpeg.
fn djpeg_outcome(file: &[u8]) -> Option<Result<Vec<u8>, String>> {
    let dir = tempdir();
    let path = dir.join("in.jpg");
    std::fs::write(&path, file).unwrap();
    let out = Command::new("djpeg").args(["-dct", "int", "-nosmooth", "-pnm"]).arg(&path).output();
    let _ = std::fs::remove_dir_all(&dir);
    let out = out.ok()?;
    let said = String::from_utf8_lossy(&out.stderr).trim().to_string();
    if !matches!(out.status.code(), Some(0 | 2)) || out.stdout.is_empty() {
        return Some(Err(said));
    }
    if !said.is_empty() {
        eprintln!("djpeg warned: {said}");
    }
    // PNM: magic, width, height, maxval, one whitespace byte, then samples.
    let mut fields = 0;
    let mut i = 0;
    let bytes = out.stdout;
    while fields < 4 {
        while bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        while !bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        fields += 1;
    }
    Some(Ok(bytes[i + 1..].to_vec()))
}

fn tempdir() -> std::path::PathBuf {
    use std::sync::atomic::{AtomicUsize, Ordering};
    static N: AtomicUsize = AtomicUsize::new(0);
    let d = std::env::temp_dir().join(format!(
        "nmat-jpeg-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::SeqCst)
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn have_djpeg() -> bool {
    let found = Command::new("djpeg").arg("-version").output().is_ok();
    if !found {
        eprintln!("djpeg not found (apt-get install libjpeg-turbo-progs): not compared with it");
    }
    found
}

const SIZES: [(u32, u32); 6] = [(1, 1), (17, 9), (8, 8), (33, 47), (64, 64), (100, 37)];

#[test]
fn indexed_streams_decode_like_djpeg_texel_by_texel_and_row_by_row() {
    let compare = have_djpeg();
    let mut worst = 0u8;
    for (w, h) in SIZES {
        for (components, sampling, name) in MODES {
            for (quality, restart) in [(40, 0), (92, 3)] {
                let what = format!("{w}×{h} {name} q{quality} restart {restart}");
                let file = jpeg(w, h, components, sampling, quality, restart);
                let indexed = index_jpeg(&file).unwrap_or_else(|e| panic!("{what}: {e}"));
                let bytes = material_from_jpeg(&indexed, "test.png").to_bytes().unwrap();
                let m = Container::parse(&bytes).unwrap();
                assert_eq!(m.codec(), nmat_core::Codec::Jpeg);
                // Packed, without the index: smaller, and the index rebuilt to the same bytes
                // (with and without restart markers; FORMAT.md §12.5).
                let packed = nmat_core::pack(&bytes).unwrap_or_else(|e| panic!("{what}: {e}"));
                assert!(packed.len() < bytes.len(), "{what}: {} vs {}", packed.len(), bytes.len());
                let unpacked = nmat_core::unpack(&packed, Default::default()).unwrap();
                assert!(unpacked.as_ref() == bytes.as_slice(), "{what}: unpacking differs");
                // Texel by texel (each MCU decoded on its own, in random order of access).
                let n = components;
                let mut texels = vec![0u8; (w * h) as usize * n];
                for y in (0..h).rev() {
                    for x in (0..w).rev() {
                        let at = ((y * w + x) as usize) * n;
                        let k = m
                            .decode_texel_u8(
                                x.into(),
                                y.into(),
                                0,
                                ChannelMask::ALL,
                                &mut texels[at..at + n],
                            )
                            .unwrap();
                        assert_eq!(k, n);
                    }
                }
                // Row by row through the prepared decoder: the same codes.
                let decoder = Decoder::new(&m);
                let mut rows = vec![0u8; texels.len()];
                for (y, row) in rows.chunks_exact_mut((w as usize) * n).enumerate() {
                    decoder
                        .decode_span_u8(&m, 0, y as i64, 0, w as usize, ChannelMask::ALL, row)
                        .unwrap();
                }
                assert_eq!(rows, texels, "{what}: spans differ from texels");
                if compare {
                    let want = djpeg(&file).unwrap();
                    assert_eq!(want.len(), texels.len(), "{what}");
                    // Exactly: the same integer IDCT, replication and colour conversion.
                    for (i, (&a, &b)) in texels.iter().zip(&want).enumerate() {
                        worst = worst.max(a.abs_diff(b));
                        assert_eq!(a, b, "{what}: sample {i} is {a}, djpeg {b}");
                    }
                }
            }
        }
    }
    eprintln!("largest difference from djpeg -dct int -nosmooth: {worst}");
}

#[test]
fn texels_of_other_channels_and_addresses_follow_the_material_rules() {
    let file = jpeg(40, 24, 3, SamplingFactor::R_4_2_0, 80, 0);
    let bytes = material_from_jpeg(&index_jpeg(&file).unwrap(), "test.png").to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let mut all = [0u8; 3];
    m.decode_texel_u8(5, 7, 0, ChannelMask::ALL, &mut all).unwrap();
    // One channel alone, 16-bit codes, float values and wrapped addresses agree.
    let mut g = [0u8; 1];
    m.decode_texel_u8(5, 7, 0, ChannelMask::single(1), &mut g).unwrap();
    assert_eq!(g[0], all[1]);
    let mut wide = [0u16; 3];
    m.decode_texel_u16(5 + 40, 7 - 24, 3, ChannelMask::ALL, &mut wide).unwrap();
    assert_eq!(wide, all.map(|c| u16::from(c) * 257));
    let mut f = [0f32; 3];
    m.decode_texel(5, 7, 0, ChannelMask::ALL, &mut f).unwrap();
    assert_eq!(f, all.map(|c| f32::from(c) / 255.0));
}

#[test]
fn files_that_cannot_be_indexed_say_why() {
    let mut progressive = Vec::new();
    let mut e = Encoder::new(&mut progressive, 80);
    e.set_progressive(true);
    e.encode(&pattern(32, 32, 3, 1), 32, 32, ColorType::Rgb).unwrap();
    assert_eq!(index_jpeg(&progressive), Err(JpegError::Progressive));
    assert!(index_jpeg(&progressive).unwrap_err().to_string().contains("jpegtran"));
    assert_eq!(index_jpeg(b"\x89PNG\r\n"), Err(JpegError::NotJpeg));
    let file = jpeg(32, 32, 3, SamplingFactor::R_4_2_0, 80, 0);
    for cut in [3, 20, file.len() / 2, file.len() - 2] {
        let err = index_jpeg(&file[..cut]).unwrap_err();
        assert!(
            matches!(err, JpegError::Truncated { .. } | JpegError::Corrupt { .. }),
            "cut at {cut}: {err}"
        );
    }
}

#[test]
fn damaged_jpeg_materials_are_refused_or_decode_without_panicking() {
    use nmat_core::ParseOptions;
    let file = jpeg(24, 20, 3, SamplingFactor::R_4_2_0, 75, 0);
    let bytes = material_from_jpeg(&index_jpeg(&file).unwrap(), "test.png").to_bytes().unwrap();
    let decode_all = |m: &nmat_core::Material<'_>| {
        let mut out = [0u8; 3];
        for y in 0..20 {
            for x in 0..24 {
                m.decode_texel_u8(x, y, 0, ChannelMask::ALL, &mut out).unwrap();
            }
        }
        let decoder = Decoder::new(m);
        let mut row = vec![0u8; 24 * 3];
        decoder.decode_span_u8(m, -5, 3, 0, 24, ChannelMask::ALL, &mut row).unwrap();
    };
    let unchecked = ParseOptions { verify_checksum: false };
    // Every truncation is refused.
    for cut in 0..bytes.len() {
        assert!(Container::parse_with(&bytes[..cut], unchecked).is_err(), "cut at {cut}");
    }
    // Every single-bit flip is refused by the checksum, and without it either refused with a
    // typed error or decodes (entropy-coded data has no redundancy to check).
    let (mut refused, mut decoded) = (0, 0);
    for bit in 0..bytes.len() * 8 {
        let mut bad = bytes.clone();
        bad[bit / 8] ^= 1 << (bit % 8);
        assert!(Container::parse(&bad).is_err(), "bit {bit} passed the checksum");
        match Container::parse_with(&bad, unchecked) {
            Ok(m) => {
                decode_all(&m);
                decoded += 1;
            }
            Err(e) => {
                assert!(!e.to_string().is_empty());
                refused += 1;
            }
        }
    }
    eprintln!("{refused} flips refused, {decoded} decoded");
    assert!(refused > 0 && decoded > 0);
}

#[test]
fn float_spans_equal_float_texels() {
    let file = jpeg(40, 24, 3, SamplingFactor::R_4_2_0, 80, 0);
    let bytes = material_from_jpeg(&index_jpeg(&file).unwrap(), "test.png").to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let decoder = Decoder::new(&m);
    let mask = ChannelMask(0b101);
    let mut span = vec![0f32; 50 * 2];
    decoder.decode_span_f32(&m, -5, 9, 0, 50, mask, &mut span).unwrap();
    for (i, pair) in span.chunks_exact(2).enumerate() {
        let mut want = [0f32; 2];
        m.decode_texel(i as i64 - 5, 9, 0, mask, &mut want).unwrap();
        assert_eq!(pair, want, "texel {i}");
    }
}

/// `nmat encode --codec jpeg`: the bundled brick material (albedo, normal, roughness, height).
mod encode {
    use nmat_core::{Codec, Container, JpegMap};
    use nmat_encode::jpeg::{JpegOptions, Subsampling, encode_jpeg, encode_jpeg_to_rate};
    use nmat_encode::{EncodeError, EncodeOption};

    fn options(quality: u8) -> JpegOptions {
        JpegOptions { quality, ..JpegOptions::default() }
    }

    fn map(first_channel: u8, channel_count: u8, luma_h: u8, luma_v: u8) -> JpegMap {
        JpegMap { first_channel, channel_count, luma_h, luma_v }
    }

    #[test]
    fn every_map_and_mip_is_stored_and_quality_buys_fidelity() {
        let set = nmat_encode::demo::bricks(64);
        let mut last = (0.0, 0.0);
        for q in [10, 50, 90] {
            let e = encode_jpeg(&set, &options(q)).unwrap();
            let m = Container::parse(&e.bytes).unwrap();
            assert_eq!(m.codec(), Codec::Jpeg);
            assert_eq!(m.mip_count(), 7);
            // Albedo is colour (4:2:0 by default); the normal is data (4:4:4); the rest gray.
            let expected = [map(0, 3, 2, 2), map(3, 3, 1, 1), map(6, 1, 1, 1), map(7, 1, 1, 1)];
            assert_eq!(m.jpeg().unwrap().maps(), expected);
            assert_eq!(e.jpeg_quality, q);
            // The rate is the packed file's (streams without their index), the fixed-rate one
            // beside it.
            assert!((e.quality.bppc - m.bppc_of(e.file().len())).abs() < 1e-12);
            assert!((e.quality.memory_bppc - m.bppc()).abs() < 1e-12);
            assert!(e.file().len() < e.bytes.len());
            assert!(
                e.quality.psnr > last.0 && e.quality.bppc > last.1,
                "quality {q}: {:.2} dB at {:.3} BPPC after {:?}",
                e.quality.psnr,
                e.quality.bppc,
                last
            );
            last = (e.quality.psnr, e.quality.bppc);
        }
        // The same inputs give the same bytes.
        assert_eq!(encode_jpeg(&set, &options(90)).unwrap().bytes, {
            encode_jpeg(&set, &options(90)).unwrap().bytes
        });
        let full = JpegOptions { subsampling: Subsampling::S444, ..options(90) };
        let m444 = encode_jpeg(&set, &full).unwrap();
        let m = Container::parse(&m444.bytes).unwrap();
        assert_eq!(m.jpeg().unwrap().maps()[0], map(0, 3, 1, 1));
        // This albedo's colour varies texel to texel: half-resolution chroma loses most of it.
        assert!(
            m444.quality.mse[0][0] < encode_jpeg(&set, &options(90)).unwrap().quality.mse[0][0]
        );
        assert!(m444.quality.psnr > 33.0, "quality 90, 4:4:4: {:.2} dB", m444.quality.psnr);
    }

    #[test]
    fn a_constant_channel_decodes_to_its_value_exactly() {
        let mut set = nmat_encode::demo::bricks(32);
        let c = set.channel_count();
        set.channels[7].constant = Some(0.25);
        for mip in &mut set.mips {
            mip.data.iter_mut().skip(7).step_by(c).for_each(|v| *v = 0.25);
        }
        let e = encode_jpeg(&set, &options(40)).unwrap();
        assert!(e.quality.mse.iter().all(|per_channel| per_channel[7] == 0.0));
        assert!(e.quality.mse[0][6] > 0.0);
    }

    #[test]
    fn a_rate_gives_the_highest_quality_within_it() {
        let set = nmat_encode::demo::bricks(64);
        for target in [1.2, 2.0] {
            let e = encode_jpeg_to_rate(&set, target, &options(85)).unwrap();
            assert!(e.quality.bppc <= target, "{} > {target}", e.quality.bppc);
            assert!(e.jpeg_quality < 100);
            let above = encode_jpeg(&set, &options(e.jpeg_quality + 1)).unwrap();
            assert!(above.quality.bppc > target, "quality {} fits too", e.jpeg_quality + 1);
        }
        // Below what quality 1 costs: quality 1, over the rate.
        let e = encode_jpeg_to_rate(&set, 0.01, &options(85)).unwrap();
        assert_eq!(e.jpeg_quality, 1);
        assert!(e.quality.bppc > 0.01);
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let err = encode_jpeg_to_rate(&set, bad, &options(85)).err().unwrap();
            assert!(
                matches!(err, EncodeError::BadOption { option: EncodeOption::Bppc, .. }),
                "{err}"
            );
        }
        for bad in [0, 101] {
            let err = encode_jpeg(&set, &options(bad)).err().unwrap();
            assert!(
                matches!(err, EncodeError::BadOption { option: EncodeOption::Quality, .. }),
                "{err}"
            );
        }
    }
}

/// The committed JPEG fixtures (tests/fixtures/jpeg/README.md; the 4:2:0 one is the C API
/// test's): each `.nmat` is its `.jpg` indexed today, each `.u8` is djpeg's decode of the `.jpg`,
/// and the material decodes to it.
#[test]
fn the_committed_jpeg_fixtures_are_their_jpegs_indexed_and_decode_like_djpeg() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/jpeg");
    for name in nmat_tests::JPEG_FIXTURES {
        let read = |ext: &str| std::fs::read(dir.join(format!("{name}.{ext}"))).unwrap();
        let (jpg, nmat, expected) = (read("jpg"), read("nmat"), read("u8"));
        let source = format!("{name}.png");
        let indexed = material_from_jpeg(&index_jpeg(&jpg).unwrap(), &source).to_bytes().unwrap();
        assert!(indexed == nmat, "{name}: indexing the .jpg no longer gives the committed .nmat");
        if let Some(samples) = djpeg(&jpg) {
            assert!(samples == expected, "{name}: djpeg no longer gives the committed .u8");
        }
        let m = Container::parse(&nmat).unwrap();
        assert_eq!(m.mip_size(0), (37, 21));
        let decoded = decode_material(&nmat);
        assert!(decoded == expected, "{name}: the material no longer decodes to the committed .u8");
        // What the quality measures compare with the source (tiles of whole MCU rows).
        let unit: Vec<f32> = expected.iter().map(|&c| f32::from(c) / 255.0).collect();
        assert!(nmat_encode::metrics::decode_mip(&m, 0) == unit, "{name}: metrics::decode_mip");
    }
}

/// The inputs the `jpeg` fuzz target found (fuzz/regressions/jpeg/): indexed once, each made a
/// material the parser refused; now the indexer refuses them with the reason.
#[test]
fn fuzz_found_jpeg_files_are_refused_with_the_reason() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/regressions/jpeg");
    let read = |name: &str| std::fs::read(dir.join(name)).unwrap();
    let e = index_jpeg(&read("dc-table-with-symbol-48.jpg")).unwrap_err();
    assert!(e.to_string().contains("a symbol baseline JPEG does not have"), "{e}");
    let e = index_jpeg(&read("mcus-run-past-a-restart-marker.jpg")).unwrap_err();
    assert!(matches!(e, JpegError::Corrupt { mcu: 2, .. }), "{e}");
    // The seed they grew from still indexes.
    assert!(index_jpeg(&read("restart-markers-420-37x21.jpg")).is_ok());
}

/// `Decoder::decode_region_u8` (each MCU decoded once) gives the codes of row spans, leaves the
/// bytes between rows alone and refuses what does not fit; the same for a neural material.
#[test]
fn regions_equal_row_spans_for_both_codecs() {
    use nmat_core::{Argument, Error};
    let jpeg = nmat_encode::jpeg::encode_jpeg(
        &nmat_encode::demo::bricks(64),
        &nmat_encode::jpeg::JpegOptions { quality: 60, ..Default::default() },
    )
    .unwrap()
    .bytes;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures");
    let neural = std::fs::read(dir.join("ntc_pbr10_96x80_clamp.nmat")).unwrap();
    for bytes in [&jpeg, &neural] {
        let m = Container::parse(bytes).unwrap();
        let d = Decoder::new(&m);
        let (w, h) = m.mip_size(0);
        for (mip, rect, mask) in [
            (0, (0, 0, w, h), ChannelMask::ALL),
            (0, (5, 3, 27, 19), ChannelMask(0b1010_0001)),
            (1, (1, 15, 9, 2), ChannelMask(0b10)),
            (2, (0, 0, 1, 1), ChannelMask::ALL),
        ] {
            let n = m.resolve_channels(mask).unwrap().count_ones() as usize;
            let (x0, y0, rw, rh) = rect;
            let pitch = rw as usize * n + 3;
            let mut out = vec![0xEEu8; pitch * rh as usize];
            assert_eq!(
                d.decode_region_u8(&m, mip, rect, mask, &mut out, pitch).unwrap(),
                rw as usize * n
            );
            for y in 0..rh as usize {
                let mut span = vec![0u8; rw as usize * n];
                d.decode_span_u8(
                    &m,
                    i64::from(x0),
                    i64::from(y0) + y as i64,
                    mip,
                    rw as usize,
                    mask,
                    &mut span,
                )
                .unwrap();
                assert!(out[y * pitch..y * pitch + span.len()] == span[..], "{rect:?} row {y}");
                assert!(out[y * pitch + span.len()..(y + 1) * pitch].iter().all(|&b| b == 0xEE));
            }
        }
        let mut out = vec![0u8; 4096];
        let bad = |r: Result<usize, Error>| match r {
            Err(Error::BadArgument { argument, .. }) => argument,
            other => panic!("{other:?}"),
        };
        assert_eq!(
            bad(d.decode_region_u8(&m, 99, (0, 0, 1, 1), ChannelMask::ALL, &mut out, 0)),
            Argument::Mip
        );
        assert_eq!(
            bad(d.decode_region_u8(&m, 0, (w - 1, 0, 2, 1), ChannelMask::ALL, &mut out, 0)),
            Argument::Region
        );
        assert_eq!(
            bad(d.decode_region_u8(&m, 0, (0, 0, 4, 2), ChannelMask::ALL, &mut out, 5)),
            Argument::RowPitch
        );
        assert_eq!(
            bad(d.decode_region_u8(&m, 0, (0, 0, w, h), ChannelMask::ALL, &mut out, 0)),
            Argument::Output
        );
        // A pitch whose rows would wrap around the address space.
        let one = ChannelMask::single(0);
        let huge = d.decode_region_u8(&m, 0, (0, 0, 1, 3), one, &mut out, 1 << 63);
        assert_eq!(bad(huge), Argument::RowPitch);
        if let Some(j) = m.jpeg() {
            assert!(j.stream_parts(0, m.mip_count() - 1).is_some());
            assert!(j.stream_parts(0, m.mip_count()).is_none());
        }
    }
}

/// Every texel of a one-mip material, channels interleaved, in raster order.
fn decode_material(bytes: &[u8]) -> Vec<u8> {
    let m = Container::parse(bytes).unwrap();
    let (w, h) = m.mip_size(0);
    let mut decoded = Vec::new();
    for y in 0..i64::from(h) {
        for x in 0..i64::from(w) {
            let mut t = [0u8; 16];
            let n = m.decode_texel_u8(x, y, 0, ChannelMask::ALL, &mut t).unwrap();
            decoded.extend_from_slice(&t[..n]);
        }
    }
    decoded
}

/// Where each marker segment before the first scan starts and how many bytes it takes (marker
/// and length field included).
fn segments(file: &[u8]) -> Vec<(usize, u8, usize)> {
    let mut out = Vec::new();
    let mut pos = 2;
    loop {
        assert_eq!(file[pos], 0xFF);
        let marker = file[pos + 1];
        let len = 2 + usize::from(u16::from_be_bytes([file[pos + 2], file[pos + 3]]));
        out.push((pos, marker, len));
        if marker == 0xDA {
            return out;
        }
        pos += len;
    }
}

/// `file` without its segments of `marker` (e.g. APP0, the JFIF marker).
fn without(file: &[u8], marker: u8) -> Vec<u8> {
    let mut out = file.to_vec();
    for (at, _, len) in segments(file).into_iter().rev().filter(|s| s.1 == marker) {
        out.drain(at..at + len);
    }
    out
}

/// `file` with a segment of `marker` holding `data` right after its start-of-image marker.
fn with_segment(file: &[u8], marker: u8, data: &[u8]) -> Vec<u8> {
    let len = u16::try_from(data.len() + 2).unwrap().to_be_bytes();
    let mut segment = vec![0xFF, marker, len[0], len[1]];
    segment.extend_from_slice(data);
    let mut out = file.to_vec();
    out.splice(2..2, segment);
    out
}

/// An Adobe APP14 marker's data (version 100, no flags) with this colour transform.
fn adobe(transform: u8) -> Vec<u8> {
    let mut data = b"Adobe".to_vec();
    data.extend_from_slice(&[0, 100, 0, 0, 0, 0, transform]);
    data
}

/// `file` with its components renamed `ids` (frame order), in the frame and the scan header.
fn with_component_ids(file: &[u8], ids: &[u8]) -> Vec<u8> {
    let mut out = file.to_vec();
    let segs = segments(file);
    let &(sof, _, _) = segs.iter().find(|s| s.1 == 0xC0).unwrap();
    let old: Vec<u8> = (0..ids.len()).map(|c| file[sof + 10 + 3 * c]).collect();
    for (c, &id) in ids.iter().enumerate() {
        out[sof + 10 + 3 * c] = id;
    }
    let &(sos, _, _) = segs.last().unwrap();
    for k in 0..usize::from(file[sos + 4]) {
        let at = sos + 5 + 2 * k;
        out[at] = ids[old.iter().position(|&id| id == file[at]).unwrap()];
    }
    out
}

/// `file` with component `c`'s sampling factors byte (h in the high nibble) set to `hv`.
fn with_sampling(file: &[u8], c: usize, hv: u8) -> Vec<u8> {
    let mut out = file.to_vec();
    let &(sof, _, _) = segments(file).iter().find(|s| s.1 == 0xC0).unwrap();
    out[sof + 11 + 3 * c] = hv;
    out
}

/// libjpeg's YCbCr to RGB (jdcolor.c: 16-bit fixed point, rounded, clamped), to recognise a
/// decode that left the samples unconverted.
fn ycc_to_rgb(ycc: &[u8]) -> Vec<u8> {
    let fix = |x: f64| (x * 65536.0 + 0.5) as i32;
    let half = 1 << 15;
    let mut out = Vec::with_capacity(ycc.len());
    for t in ycc.chunks_exact(3) {
        let (y, cb, cr) = (i32::from(t[0]), i32::from(t[1]) - 128, i32::from(t[2]) - 128);
        let r = y + ((fix(1.402) * cr + half) >> 16);
        let g = y + ((-fix(0.34414) * cb - fix(0.71414) * cr + half) >> 16);
        let b = y + ((fix(1.772) * cb + half) >> 16);
        out.extend([r, g, b].map(|v| v.clamp(0, 255) as u8));
    }
    out
}

/// libjpeg's colour-space rules for three components (libjpeg-turbo jdapimin.c,
/// `default_decompress_parms`): JFIF marker → YCbCr; else Adobe marker, transform 0 → RGB,
/// others → YCbCr; else IDs 'R','G','B' → RGB, others → YCbCr. Made from the committed fixture
/// (cjpeg: JFIF, IDs 1, 2, 3, 4:2:0, restarts) by editing markers and IDs: a file taken as YCbCr
/// decodes as djpeg decodes it; one taken as RGB is refused, and djpeg's decode of it is the
/// fixture's samples left unconverted (libjpeg's YCbCr → RGB of it is the fixture's decode).
#[test]
fn three_components_are_ycbcr_or_refused_as_rgb_by_libjpeg_rules() {
    use nmat_encode::jpeg::RgbRule;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/jpeg");
    let jfif = std::fs::read(dir.join("pattern_420_37x21.jpg")).unwrap();
    let ycc_decode = std::fs::read(dir.join("pattern_420_37x21.u8")).unwrap();
    let bare = without(&jfif, 0xE0);
    assert_eq!(segments(&jfif).len(), segments(&bare).len() + 1, "the fixture has one APP0");
    let rgb_ids = |f: &[u8]| with_component_ids(f, b"RGB");
    // APP0 "JFIF\0" with 13 of the 14 bytes libjpeg needs to take it as a JFIF marker.
    let short_jfif = with_segment(&rgb_ids(&bare), 0xE0, b"JFIF\0\x01\x01\0\0\x01\0\x01");
    let cases: [(&str, Vec<u8>, Option<RgbRule>); 11] = [
        ("JFIF, IDs R,G,B", rgb_ids(&jfif), None),
        ("JFIF and Adobe transform 0", with_segment(&jfif, 0xEE, &adobe(0)), None),
        ("Adobe transform 0", with_segment(&bare, 0xEE, &adobe(0)), Some(RgbRule::AdobeTransform0)),
        ("Adobe transform 1, IDs R,G,B", with_segment(&rgb_ids(&bare), 0xEE, &adobe(1)), None),
        ("Adobe transform 2, IDs R,G,B", with_segment(&rgb_ids(&bare), 0xEE, &adobe(2)), None),
        ("no marker, IDs R,G,B", rgb_ids(&bare), Some(RgbRule::ComponentIdsRgb)),
        ("short JFIF APP0, IDs R,G,B", short_jfif, Some(RgbRule::ComponentIdsRgb)),
        ("no marker, IDs 1,2,3", bare.clone(), None),
        ("no marker, IDs 0,1,2", with_component_ids(&bare, &[0, 1, 2]), None),
        ("no marker, IDs r,g,b", with_component_ids(&bare, b"rgb"), None),
        ("no marker, IDs B,G,R", with_component_ids(&bare, b"BGR"), None),
    ];
    for (what, file, rgb) in cases {
        let djpeg = djpeg_outcome(&file).map(|r| r.unwrap_or_else(|e| panic!("{what}: {e}")));
        match rgb {
            None => {
                let indexed = index_jpeg(&file).unwrap_or_else(|e| panic!("{what}: {e}"));
                let bytes = material_from_jpeg(&indexed, "test.png").to_bytes().unwrap();
                let decoded = decode_material(&bytes);
                assert!(decoded == ycc_decode, "{what}: not the fixture's YCbCr decode");
                if let Some(samples) = djpeg {
                    assert!(samples == decoded, "{what}: djpeg decodes it otherwise");
                }
            }
            Some(rule) => {
                let err = index_jpeg(&file).unwrap_err();
                assert_eq!(err, JpegError::NotYCbCr { rule }, "{what}");
                let message = err.to_string();
                let why = match rule {
                    RgbRule::AdobeTransform0 => "Adobe APP14 marker says transform 0",
                    _ => "component IDs are 'R', 'G', 'B'",
                };
                assert!(message.contains(why) && message.contains("cjpeg"), "{message}");
                if let Some(samples) = djpeg {
                    assert!(samples != ycc_decode, "{what}: djpeg decodes it as YCbCr");
                    assert!(
                        ycc_to_rgb(&samples) == ycc_decode,
                        "{what}: djpeg's RGB is not Y, Cb, Cr"
                    );
                }
            }
        }
    }
}

/// Sampling factors outside 1 … 4 are refused for every component, gray included, as libjpeg
/// refuses them (`JERR_BAD_SAMPLING`); a gray file's valid factors change nothing (one
/// component: an MCU is one block), as in djpeg.
#[test]
fn sampling_factors_outside_1_to_4_are_refused_and_a_gray_file_ignores_valid_ones() {
    let gray = jpeg(17, 9, 1, SamplingFactor::F_1_1, 80, 0);
    let &(sof, _, _) = segments(&gray).iter().find(|s| s.1 == 0xC0).unwrap();
    let gray_id = gray[sof + 10];
    let plain = decode_material(
        &material_from_jpeg(&index_jpeg(&gray).unwrap(), "g.png").to_bytes().unwrap(),
    );
    for hv in [0x12, 0x21, 0x22, 0x14, 0x41, 0x44, 0x34] {
        let file = with_sampling(&gray, 0, hv);
        let what = format!("gray {}×{}", hv >> 4, hv & 15);
        let indexed = index_jpeg(&file).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!((indexed.map.luma_h, indexed.map.luma_v), (1, 1), "{what}");
        let decoded = decode_material(&material_from_jpeg(&indexed, "g.png").to_bytes().unwrap());
        assert!(decoded == plain, "{what}: decodes otherwise than 1×1");
        if let Some(samples) = djpeg_outcome(&file) {
            assert!(samples.unwrap_or_else(|e| panic!("{what}: {e}")) == decoded, "{what}: djpeg");
        }
    }
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/jpeg");
    let colour = std::fs::read(dir.join("pattern_420_37x21.jpg")).unwrap();
    for (what, file, c, id, hv) in [
        ("gray 0×0", with_sampling(&gray, 0, 0x00), 0, gray_id, 0x00),
        ("gray 5×1", with_sampling(&gray, 0, 0x51), 0, gray_id, 0x51),
        ("gray 1×0", with_sampling(&gray, 0, 0x10), 0, gray_id, 0x10),
        ("colour luma 5×5", with_sampling(&colour, 0, 0x55), 0, 1, 0x55),
        ("colour Cb 0×0", with_sampling(&colour, 1, 0x00), 1, 2, 0x00),
        ("colour Cr 1×15", with_sampling(&colour, 2, 0x1F), 2, 3, 0x1F),
    ] {
        let err = index_jpeg(&file).unwrap_err();
        let want = JpegError::BadSampling { component: c, id, h: hv >> 4, v: hv & 15 };
        assert_eq!(err, want, "{what}");
        let message = err.to_string();
        assert!(message.contains(&format!("component {c} (ID {id})")), "{message}");
        assert!(message.contains(&format!("{}×{}", hv >> 4, hv & 15)), "{message}");
        if let Some(outcome) = djpeg_outcome(&file) {
            let said = outcome.err().unwrap_or_else(|| panic!("{what}: djpeg decodes it"));
            eprintln!("{what}: djpeg: {said}");
        }
    }
}
