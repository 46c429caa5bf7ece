//! The `nmat` binary end to end: encode → info → decode → eval, determinism across thread counts,
//! and bad input that fails cleanly without leaving partial files.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn nmat(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nmat")).args(args).output().expect("run nmat")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nmat-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Writes the procedural brick material's mip 0 as PNG maps.
fn write_maps(dir: &Path, size: u32) {
    nmat_cli::output::write_source_maps(&nmat_encode::demo::bricks(size), dir).unwrap();
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn encode_info_decode_eval_round_trip() {
    let dir = temp_dir("roundtrip");
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    write_maps(&src, 64);
    let file = dir.join("bricks.nmat");
    let o = nmat(&[
        "encode",
        src.to_str().unwrap(),
        "-o",
        file.to_str().unwrap(),
        "--steps",
        "200",
        "--profile",
        "ntc-1.0",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("overall: PSNR"), "{}", text(&o));

    let o = nmat(&["info", file.to_str().unwrap()]);
    let info = text(&o);
    assert!(o.status.success(), "{info}");
    for needle in [
        "64×64",
        "7 mips",
        "8 channels",
        "bricks_normal.png",
        "bits per pixel per channel",
        "latent grids",
        "byte budget",
        "network (int8 weights, row scales, biases)",
        // Packed (2.2's sections) with 2.3's LOD feature.
        ".nmat format 2.3",
        "LOD input mip/2",
        "latents entropy-coded",
        "in memory",
    ] {
        assert!(info.contains(needle), "info lacks {needle}: {info}");
    }
    // Unpacked, the packed file is its in-memory (fixed-rate) form: the layout the budget's
    // file line sizes, larger than the nominal one --fixed-rate trains (the memory factor).
    let unpacked = dir.join("unpacked.nmat");
    let o = nmat(&["unpack", file.to_str().unwrap(), "-o", unpacked.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let unpacked_size = std::fs::metadata(&unpacked).unwrap().len();
    let file_line = info.lines().find(|l| l.trim_start().starts_with("file ")).unwrap();
    assert!(file_line.contains(&format!(" {unpacked_size} bytes")), "{file_line}");
    let o =
        nmat(&["pack", unpacked.to_str().unwrap(), "-o", dir.join("re.nmat").to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(std::fs::read(dir.join("re.nmat")).unwrap() == std::fs::read(&file).unwrap());
    // The same encode with --fixed-rate is that of --memory-factor 1 unpacked, byte for byte.
    let encode = |out: &Path, extra: &str| {
        let mut args = vec!["encode", src.to_str().unwrap(), "-o", out.to_str().unwrap()];
        args.extend(["--steps", "200", "--profile", "ntc-1.0", extra]);
        nmat(&args)
    };
    let (fixed, nominal) = (dir.join("fixed.nmat"), dir.join("nominal.nmat"));
    let o = encode(&fixed, "--fixed-rate");
    assert!(o.status.success(), "{}", text(&o));
    let o = encode(&nominal, "--memory-factor=1");
    assert!(o.status.success(), "{}", text(&o));
    let o = nmat(&["unpack", nominal.to_str().unwrap(), "-o", unpacked.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let fixed_bytes = std::fs::read(&fixed).unwrap();
    assert!(std::fs::read(&unpacked).unwrap() == fixed_bytes, "unpack differs from --fixed-rate");
    assert!((fixed_bytes.len() as u64) < unpacked_size, "the memory factor gave no room");
    let packed_size = std::fs::metadata(&nominal).unwrap().len();
    assert!(packed_size < fixed_bytes.len() as u64, "{packed_size} vs {}", fixed_bytes.len());
    let fixed_info = text(&nmat(&["info", fixed.to_str().unwrap()]));
    assert!(fixed_info.contains(".nmat format 2.3") && !fixed_info.contains("entropy-coded"));
    // For decoders before 2.3: the LOD feature they know, fixed-rate as 2.0 wrote it.
    let legacy = dir.join("legacy.nmat");
    let o = nmat(&[
        "encode",
        src.to_str().unwrap(),
        "-o",
        legacy.to_str().unwrap(),
        "--steps",
        "20",
        "--fixed-rate",
        "--legacy-lod",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let legacy_info = text(&nmat(&["info", legacy.to_str().unwrap()]));
    assert!(legacy_info.contains(".nmat format 2.0") && legacy_info.contains("LOD input mip/16"));
    let o = encode(&dir.join("no.nmat"), "--memory-factor=2.5");
    assert!(!o.status.success() && text(&o).contains("--memory-factor 2.5"), "{}", text(&o));
    for (bad, shown) in [("--output-margin=0.3", "0.3"), ("--output-margin=-1", "-1")] {
        let o = encode(&dir.join("no.nmat"), bad);
        let message = text(&o);
        assert!(!o.status.success() && message.contains(&format!("--output-margin {shown}:")));
    }
    assert!(!dir.join("no.nmat").exists());
    // `nmat pack` of the fixed-rate file is the packed file; neither replaces its input.
    let repacked = dir.join("repacked.nmat");
    let o = nmat(&["pack", fixed.to_str().unwrap(), "-o", repacked.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(std::fs::read(&repacked).unwrap() == std::fs::read(&nominal).unwrap());
    let o = nmat(&["pack", fixed.to_str().unwrap(), "-o", fixed.to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("is one of the inputs"), "{}", text(&o));

    // --dry-run prints the same budget for the same layout, and writes nothing.
    let planned = dir.join("planned.nmat");
    let o = nmat(&[
        "encode",
        src.to_str().unwrap(),
        "-o",
        planned.to_str().unwrap(),
        "--profile",
        "ntc-1.0",
        "--dry-run",
    ]);
    let plan = text(&o);
    assert!(o.status.success(), "{plan}");
    assert!(!planned.exists(), "--dry-run wrote a file");
    let plan_file_line = plan.lines().find(|l| l.trim_start().starts_with("file ")).unwrap();
    assert_eq!(plan_file_line, file_line, "{plan}");

    let out = dir.join("out");
    let o = nmat(&["decode", file.to_str().unwrap(), "-o", out.to_str().unwrap(), "--mip", "all"]);
    assert!(o.status.success(), "{}", text(&o));
    let written = files_in(&out);
    assert_eq!(written.len(), 4 * 7, "{written:?}");
    for name in ["bricks_albedo_mip0.png", "bricks_height_mip6.png", "bricks_normal_mip3.png"] {
        assert!(written.contains(&name.to_string()), "{name} in {written:?}");
    }
    let albedo = image::open(out.join("bricks_albedo_mip1.png")).unwrap();
    assert_eq!((albedo.width(), albedo.height(), albedo.color()), (32, 32, image::ColorType::Rgb8));
    let rough = image::open(out.join("bricks_roughness_mip0.png")).unwrap();
    assert_eq!(rough.color(), image::ColorType::L8, "gray maps stay gray");

    let out0 = dir.join("out0");
    let o = nmat(&["decode", file.to_str().unwrap(), "-o", out0.to_str().unwrap(), "--float"]);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(
        files_in(&out0),
        ["bricks_albedo.png", "bricks_height.png", "bricks_normal.png", "bricks_roughness.png"]
    );
    // Decoding over existing files (here: over the source maps) is refused unless --force.
    let source = std::fs::read(src.join("bricks_albedo.png")).unwrap();
    let o = nmat(&["decode", file.to_str().unwrap(), "-o", src.to_str().unwrap()]);
    assert!(!o.status.success(), "decode over the sources succeeded");
    assert!(text(&o).contains("already exist") && text(&o).contains("--force"), "{}", text(&o));
    assert!(std::fs::read(src.join("bricks_albedo.png")).unwrap() == source, "source replaced");
    let o = nmat(&["decode", file.to_str().unwrap(), "-o", out0.to_str().unwrap(), "--force"]);
    assert!(o.status.success(), "{}", text(&o));
    // A file whose source maps name one file twice (checksum refreshed): the optional section is
    // damaged, so it is ignored with a warning and the maps are named after the channels.
    let mut dup = std::fs::read(&file).unwrap();
    let (from, to) = (b"bricks_height.png", b"bricks_albedo.png");
    let at = dup.windows(from.len()).position(|w| w == from).expect("map name in the file");
    dup[at..at + to.len()].copy_from_slice(to);
    let crc = nmat_core::internals::file_checksum(&dup);
    dup[20..24].copy_from_slice(&crc.to_le_bytes());
    let dup_file = dir.join("dup.nmat");
    std::fs::write(&dup_file, &dup).unwrap();
    let dup_out = dir.join("dup");
    let o = nmat(&["decode", dup_file.to_str().unwrap(), "-o", dup_out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("names bricks_albedo.png twice; ignored"), "{}", text(&o));
    assert!(files_in(&dup_out).contains(&"albedo.png".to_string()), "{:?}", files_in(&dup_out));

    let o = nmat(&["eval", file.to_str().unwrap(), "--ref", src.to_str().unwrap()]);
    let report = text(&o);
    assert!(o.status.success(), "{report}");
    let psnr: f64 = report
        .split("overall: PSNR ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{report}"));
    // Plumbing, not quality (the encoder tests judge training): well above a broken pipeline.
    assert!(psnr > 20.0, "{report}");
    // The rate is the packed file's, with the fixed-rate one beside it; a fixed-rate file
    // evaluates to the PSNR of its packed twin at its larger rate.
    let rate = |report: &str| -> f64 {
        let head = report.split(" bits per pixel per channel").next().unwrap();
        head.rsplit(", ").next().unwrap().parse().unwrap()
    };
    let pixels_channels = 64.0 * 64.0 * 8.0;
    let file_size = std::fs::metadata(&file).unwrap().len();
    assert!((rate(&report) - file_size as f64 * 8.0 / pixels_channels).abs() < 1e-3, "{report}");
    assert!(report.contains(" in memory)"), "{report}");
    let eval =
        |f: &Path| text(&nmat(&["eval", f.to_str().unwrap(), "--ref", src.to_str().unwrap()]));
    let (nominal_report, fixed_report) = (eval(&nominal), eval(&fixed));
    let size = fixed_bytes.len();
    assert!((rate(&nominal_report) - packed_size as f64 * 8.0 / pixels_channels).abs() < 1e-3);
    assert!((rate(&fixed_report) - size as f64 * 8.0 / pixels_channels).abs() < 1e-3);
    let nominal_psnr = nominal_report.split("overall: PSNR ").nth(1).unwrap().split(' ').next();
    assert!(fixed_report.contains(&format!("overall: PSNR {} dB", nominal_psnr.unwrap())));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Channels by content: gray maps of colour roles (albedo, normal, specular,
/// emissive; 8- and 16-bit; with and without alpha) are one channel each and come back in their
/// own layout; a map that is gray except for one component of one texel stays RGB.
#[test]
fn gray_maps_of_any_role_are_one_channel_and_come_back_in_their_layout() {
    let dir = temp_dir("gray");
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    let n = 32u32;
    let v = |x: u32, y: u32| ((x * 7 + y * 3) % 256) as u8;
    image::RgbImage::from_fn(n, n, |x, y| image::Rgb([v(x, y); 3]))
        .save(src.join("m_albedo.png"))
        .unwrap();
    image::RgbImage::from_fn(n, n, |x, y| image::Rgb([v(y, x); 3]))
        .save(src.join("m_normal.png"))
        .unwrap();
    // Gray with a varying alpha: two channels (gray, alpha).
    image::RgbaImage::from_fn(n, n, |x, y| {
        image::Rgba([v(x + 5, y), v(x + 5, y), v(x + 5, y), 40 + x as u8])
    })
    .save(src.join("m_specular.png"))
    .unwrap();
    // 16-bit gray RGB.
    image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(n, n, |x, y| {
        image::Rgb([(x * 2000 + y * 13) as u16; 3])
    })
    .save(src.join("m_emissive.png"))
    .unwrap();
    // Gray but for one blue component: stays RGB (no lossy guess).
    image::RgbImage::from_fn(n, n, |x, y| {
        let g = v(x, y + 1);
        image::Rgb([g, g, if (x, y) == (3, 4) { g ^ 1 } else { g }])
    })
    .save(src.join("m_gloss.png"))
    .unwrap();
    let file = dir.join("m.nmat");
    let o = nmat(&["encode", src.to_str().unwrap(), "-o", file.to_str().unwrap(), "--steps", "20"]);
    assert!(o.status.success(), "{}", text(&o));
    // stderr is not a terminal here: progress comes as plain lines, the last at 100 %.
    let progress = String::from_utf8_lossy(&o.stderr);
    assert!(progress.contains(": 2/20 steps (10 %)"), "{progress}");
    assert!(progress.contains(": 20/20 steps (100 %)"), "{progress}");
    let stored = std::fs::read(&file).unwrap();
    let bytes = nmat_core::unpack(&stored, Default::default()).unwrap();
    let m = nmat_core::Container::parse(&bytes).unwrap();
    let names: Vec<&str> = m.channels().iter().map(|c| c.name).collect();
    assert_eq!(
        names,
        ["albedo", "normal", "gloss.r", "gloss.g", "gloss.b", "specular", "specular.a", "emissive"]
    );
    let info = text(&nmat(&["info", file.to_str().unwrap()]));
    let line = |name: &str| info.lines().find(|l| l.contains(name)).unwrap_or_default().to_string();
    assert!(line("m_albedo.png").contains("R = G = B"), "{info}");
    assert!(!line("m_gloss.png").contains("R = G = B"), "{info}");

    let out = dir.join("out");
    let o = nmat(&["decode", file.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("decoded 5 files in "), "{}", text(&o));
    for (name, color) in [
        ("m_albedo.png", image::ColorType::Rgb8),
        ("m_normal.png", image::ColorType::Rgb8),
        ("m_specular.png", image::ColorType::Rgba8),
        ("m_emissive.png", image::ColorType::Rgb16),
        ("m_gloss.png", image::ColorType::Rgb8),
    ] {
        let img = image::open(out.join(name)).unwrap();
        assert_eq!((img.width(), img.height(), img.color()), (n, n, color), "{name}");
        if name != "m_gloss.png" {
            let rgba = img.to_rgba16();
            assert!(rgba.pixels().all(|p| p[0] == p[1] && p[1] == p[2]), "{name}: R = G = B");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_file_does_not_depend_on_the_thread_count() {
    let dir = temp_dir("threads");
    write_maps(&dir, 32);
    let a = dir.join("a.nmat");
    let b = dir.join("b.nmat");
    let args = |out: &Path, threads: &str| {
        vec![
            "encode".to_string(),
            dir.to_str().unwrap().to_string(),
            "-o".into(),
            out.to_str().unwrap().into(),
            "--steps".into(),
            "40".into(),
            "--seed".into(),
            "11".into(),
            "--threads".into(),
            threads.into(),
        ]
    };
    let run = |v: Vec<String>| nmat(&v.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(run(args(&a, "1")).status.success());
    assert!(run(args(&b, "2")).status.success());
    assert!(
        std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
        "1 and 2 threads gave different files"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_output_that_cannot_be_written_or_absurd_threads_are_refused_before_training() {
    let dir = temp_dir("outcheck");
    let maps = dir.join("maps");
    std::fs::create_dir_all(&maps).unwrap();
    write_maps(&maps, 16);
    let albedo = maps.join("bricks_albedo.png");
    let before = std::fs::read(&albedo).unwrap();
    let m = maps.to_str().unwrap();
    for (out, expect) in [
        (albedo.to_str().unwrap().to_string(), "is one of the inputs"),
        (dir.to_str().unwrap().to_string(), "is a directory"),
        (dir.join("nope").join("x.nmat").to_str().unwrap().to_string(), "does not exist"),
    ] {
        let o = nmat(&["encode", m, "-o", &out, "--steps", "3"]);
        assert!(!o.status.success(), "-o {out} succeeded");
        let t = text(&o);
        assert!(t.contains(expect) && !t.contains("overall: PSNR"), "-o {out}: {t}");
    }
    let out = dir.join("x.nmat");
    let o = nmat(&["encode", m, "-o", out.to_str().unwrap(), "--threads", "100000"]);
    assert!(text(&o).contains("--threads 100000: must be between 1 and"), "{}", text(&o));
    assert!(std::fs::read(&albedo).unwrap() == before, "an input map was changed");
    assert_eq!(files_in(&dir), ["maps"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_map_over_the_memory_budget_is_refused_before_it_is_decoded() {
    let dir = temp_dir("memory");
    write_maps(&dir, 64);
    let out = dir.join("m.nmat");
    let (d, o) = (dir.to_str().unwrap(), out.to_str().unwrap());
    // 64² texels at 48 bytes each: 192 KiB.
    let r = nmat(&["encode", d, "-o", o, "--max-memory", "100K", "--steps", "2"]);
    assert!(!r.status.success());
    let t = text(&r);
    assert!(t.contains("declares 64×64 texels") && t.contains("--max-memory"), "{t}");
    for bad in ["0", "12Q", "3T"] {
        let r = nmat(&["encode", d, "-o", o, "--max-memory", bad, "--steps", "2"]);
        assert!(!r.status.success() && text(&r).contains("--max-memory"), "{bad}: {}", text(&r));
    }
    assert!(!out.exists());
    let r = nmat(&["encode", d, "-o", o, "--max-memory", "1M", "--steps", "2"]);
    assert!(r.status.success(), "{}", text(&r));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `bytes` (unpacked if packed) with its SOURCE_MAPS section changed by `patch` and the checksum
/// refreshed.
fn with_source_maps(bytes: &[u8], patch: impl FnOnce(&mut [u8])) -> Vec<u8> {
    let unpacked = nmat_core::unpack(bytes, Default::default()).unwrap();
    let bytes: &[u8] = &unpacked;
    let m = nmat_core::Container::parse(bytes).unwrap();
    let kind = nmat_core::SectionKind(nmat_encode::source_maps::SECTION_KIND);
    let section = m.optional_section(kind).expect("a SOURCE_MAPS section");
    let at = section.as_ptr() as usize - bytes.as_ptr() as usize;
    let mut out = bytes.to_vec();
    patch(&mut out[at..at + section.len()]);
    let crc = nmat_core::internals::file_checksum(&out);
    out[20..24].copy_from_slice(&crc.to_le_bytes());
    out
}

#[test]
fn unwritable_source_maps_and_oversized_decodes_are_refused_before_anything_is_written() {
    let dir = temp_dir("hostile-maps");
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    write_maps(&src, 32);
    let file = dir.join("m.nmat");
    let o = nmat(&["encode", src.to_str().unwrap(), "-o", file.to_str().unwrap(), "--steps", "2"]);
    assert!(o.status.success(), "{}", text(&o));
    let bytes = std::fs::read(&file).unwrap();
    // The record of bricks_albedo.png: 8 header bytes (semantic, layout, first channel, channel
    // count, flags, alpha, 0, name length), then the name.
    let record = |s: &[u8]| s.windows(17).position(|w| w == b"bricks_albedo.png").unwrap() - 8;
    // A SOURCE_MAPS section that is damaged is ignored (names_from_files_are_made_safe_…); one
    // that asks for a layout its format cannot hold is a refusal with the way out.
    let cases: [(&str, Vec<u8>, &str); 1] = [(
        "tiff",
        with_source_maps(&bytes, |s| {
            let r = record(s);
            s[r + 1] = 2; // gray+alpha
            s[r + 3] = 2;
            s[r + 8 + 14..r + 8 + 17].copy_from_slice(b"tif");
        }),
        "bricks_albedo.tif: Tiff cannot hold a gray+alpha map",
    )];
    for (name, patched, expected) in cases {
        let path = dir.join(format!("{name}.nmat"));
        std::fs::write(&path, patched).unwrap();
        let out = dir.join(format!("{name}-out"));
        let o = nmat(&["decode", path.to_str().unwrap(), "-o", out.to_str().unwrap()]);
        assert!(!o.status.success(), "{name}: decode succeeded");
        assert!(text(&o).contains(expected), "{name}: {}", text(&o));
        assert!(text(&o).contains("nothing was written"), "{name}: {}", text(&o));
        assert!(!out.exists(), "{name}: a folder was created for a refused decode");
    }
    // The way out the TIFF error names: every map as PNG, the gray+alpha layout kept.
    let out = dir.join("tiff-png");
    let tiff = dir.join("tiff.nmat");
    let o = nmat(&["decode", tiff.to_str().unwrap(), "-o", out.to_str().unwrap(), "--png"]);
    assert!(o.status.success(), "{}", text(&o));
    let albedo = image::open(out.join("bricks_albedo.png")).unwrap();
    assert_eq!(albedo.color(), image::ColorType::La8);

    // 32² texels, 8 components in 4 maps: (8 + 4) × 2 bytes a texel = 24 KiB.
    let out = dir.join("small-budget");
    let (f, d) = (file.to_str().unwrap(), out.to_str().unwrap());
    let o = nmat(&["decode", f, "-o", d, "--max-memory", "16K"]);
    assert!(!o.status.success(), "decode over the memory budget succeeded");
    assert!(text(&o).contains("--max-memory") && text(&o).contains("nothing"), "{}", text(&o));
    assert!(!out.exists(), "a folder was created for a refused decode");
    let o = nmat(&["decode", f, "-o", d, "--max-memory", "32K"]);
    assert!(o.status.success(), "{}", text(&o));
    let expected =
        ["bricks_albedo.png", "bricks_height.png", "bricks_normal.png", "bricks_roughness.png"];
    assert_eq!(files_in(&out), expected);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn info_says_what_a_file_is_instead_of_reading_it_whole() {
    let dir = temp_dir("notnmat");
    write_maps(&dir, 16);
    let file = dir.join("m.nmat");
    let maps = dir.to_str().unwrap();
    let o = nmat(&["encode", maps, "-o", file.to_str().unwrap(), "--steps", "2"]);
    assert!(o.status.success(), "{}", text(&o));
    let mut trailing = std::fs::read(&file).unwrap();
    trailing.extend_from_slice(b"junk");
    std::fs::write(dir.join("trailing.nmat"), &trailing).unwrap();
    std::fs::write(dir.join("empty.nmat"), b"").unwrap();
    let mut cases = vec![
        (dir.join("bricks_albedo.png"), "not a .nmat file (PNG signature)"),
        (dir.join("empty.nmat"), "not a .nmat file (the file is empty)"),
        (dir.clone(), "is a folder, not a regular file"),
        (dir.join("trailing.nmat"), "4 trailing bytes after the"),
        (dir.join("missing.nmat"), "missing.nmat"),
    ];
    if cfg!(unix) {
        cases.push(("/dev/zero".into(), "not a regular file"));
    }
    for (path, says) in cases {
        let o = nmat(&["info", path.to_str().unwrap()]);
        assert!(!o.status.success(), "info {} succeeded", path.display());
        assert!(text(&o).contains(says), "info {}: {}", path.display(), text(&o));
    }
    let o = nmat(&["eval", file.to_str().unwrap(), "--ref", dir.join("gone").to_str().unwrap()]);
    assert!(text(&o).contains("gone: no such file or folder"), "{}", text(&o));
    assert!(!text(&o).contains("--map"), "eval has no --map: {}", text(&o));
    std::fs::copy(dir.join("bricks_albedo.png"), dir.join("other_albedo.png")).unwrap();
    let o = nmat(&["encode", maps, "-o", dir.join("x.nmat").to_str().unwrap()]);
    assert!(text(&o).contains("are both an albedo map"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_input_fails_cleanly_and_writes_nothing() {
    let dir = temp_dir("bad");
    let out = dir.join("never.nmat");
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![
                "encode".into(),
                empty.to_str().unwrap().into(),
                "-o".into(),
                out.to_str().unwrap().into(),
            ],
            "no image maps",
        ),
        (
            vec![
                "encode".into(),
                dir.join("nope").to_str().unwrap().into(),
                "-o".into(),
                out.to_str().unwrap().into(),
            ],
            "nope: no such file or folder",
        ),
        (
            vec![
                "encode".into(),
                "--map".into(),
                "colour=x.png".into(),
                "-o".into(),
                out.to_str().unwrap().into(),
            ],
            "--map colour=x.png",
        ),
        (
            vec![
                "encode".into(),
                empty.to_str().unwrap().into(),
                "-o".into(),
                out.to_str().unwrap().into(),
                "--profile".into(),
                "ntc-9".into(),
            ],
            "no image maps",
        ),
        (
            vec![
                "encode".into(),
                empty.to_str().unwrap().into(),
                "-o".into(),
                out.to_str().unwrap().into(),
                "--steps".into(),
                "0".into(),
            ],
            "no image maps",
        ),
    ];
    for (args, needle) in cases {
        let o = nmat(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(text(&o).contains(needle), "{args:?}: {}", text(&o));
    }
    // A corrupt map: an error naming it, and no output (not even a temporary file).
    let maps = dir.join("maps");
    std::fs::create_dir_all(&maps).unwrap();
    std::fs::write(maps.join("wall_albedo.png"), b"\x89PNG\r\n\x1a\ngarbage").unwrap();
    let o = nmat(&["encode", maps.to_str().unwrap(), "-o", out.to_str().unwrap(), "--steps", "5"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("wall_albedo.png"), "{}", text(&o));
    assert!(!out.exists());
    assert!(files_in(&dir).iter().all(|f| !f.contains(".tmp")), "{:?}", files_in(&dir));
    // A corrupt .nmat names the problem; a mip out of range is refused.
    let bad = dir.join("bad.nmat");
    std::fs::write(&bad, b"NMAT but not really").unwrap();
    let o = nmat(&["info", bad.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(text(&o).contains("truncated"), "{}", text(&o));
    write_maps(&maps, 16);
    std::fs::remove_file(maps.join("wall_albedo.png")).unwrap();
    let good = dir.join("good.nmat");
    assert!(
        nmat(&["encode", maps.to_str().unwrap(), "-o", good.to_str().unwrap(), "--steps", "5"])
            .status
            .success()
    );
    let o = nmat(&[
        "decode",
        good.to_str().unwrap(),
        "-o",
        dir.join("o").to_str().unwrap(),
        "--mip",
        "99",
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("--mip 99"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn demo_runs_end_to_end() {
    let dir = temp_dir("demo");
    let o = nmat(&["demo", "-o", dir.to_str().unwrap(), "--steps", "30"]);
    let report = text(&o);
    assert!(o.status.success(), "{report}");
    assert!(dir.join("demo.nmat").is_file());
    assert!(dir.join("source/bricks_albedo.png").is_file());
    assert!(dir.join("decoded/bricks_albedo.png").is_file());
    let overall = |t: &str| -> String {
        let line = t.lines().find(|l| l.starts_with("overall: PSNR")).unwrap_or_default();
        line.split(" dB").next().unwrap_or_default().to_string()
    };
    // The eval command the demo prints measures against the maps it encoded: the same PSNR as its
    // own report, and no warning.
    let eval = report.lines().find(|l| l.contains(" eval ")).expect("an eval command");
    let args: Vec<&str> = eval.split_whitespace().skip(1).collect();
    let o = nmat(&args);
    assert!(o.status.success(), "{}", text(&o));
    assert!(!text(&o).contains("warning"), "{}", text(&o));
    assert_eq!(overall(&text(&o)), overall(&report), "{}\n{report}", text(&o));
    assert!(report.lines().any(|l| l.contains(" bench ") && l.contains("--ref")), "{report}");
    // Against its own decoded maps: a warning that says so.
    let decoded = dir.join("decoded");
    let o = nmat(&["eval", args[1], "--ref", decoded.to_str().unwrap()]);
    assert!(text(&o).contains("warning: the maps in"), "{}", text(&o));
    assert!(text(&o).contains("look like decoded maps"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn effort_fast_is_a_quarter_of_the_default_steps_and_conflicts_with_steps() {
    let dir = temp_dir("effort");
    let (a, b) = (dir.join("a"), dir.join("b"));
    // The demo's default is 3000 steps.
    let o = nmat(&["demo", "-o", a.to_str().unwrap(), "--effort", "fast"]);
    assert!(o.status.success(), "{}", text(&o));
    let o = nmat(&["demo", "-o", b.to_str().unwrap(), "--steps", "750"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        std::fs::read(a.join("demo.nmat")).unwrap() == std::fs::read(b.join("demo.nmat")).unwrap(),
        "--effort fast and --steps 750 gave different files"
    );
    let o = nmat(&["demo", "-o", a.to_str().unwrap(), "--effort", "max", "--steps", "5"]);
    assert!(!o.status.success() && text(&o).contains("cannot be used with"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--hi-bilinear`: an NTC profile's high-resolution grids read at their 4 nearest cells only or
/// bilinearly too, whatever the profile's default (the third term is in the plan `--dry-run`
/// prints); refused for NBC profiles and the JPEG codec, naming the option.
#[test]
fn hi_bilinear_turns_the_third_term_on_and_off() {
    let dir = temp_dir("hi-bilinear");
    let src = dir.join("src");
    write_maps(&src, 128);
    let s = src.to_str().unwrap();
    let out = dir.join("x.nmat");
    let o = out.to_str().unwrap();
    let plan = |extra: &[&str]| nmat(&[&["encode", s, "-o", o, "--dry-run"][..], extra].concat());
    let twice = "level 0 (mips 0,1,2): Nearest4[0] + Bilinear[1] + Bilinear[0]";
    let once = "level 0 (mips 0,1,2): Nearest4[0] + Bilinear[1]\n";
    for (profile, flag, want) in [
        ("ntc-0.2", None, twice),
        ("ntc-0.2", Some("off"), once),
        ("ntc-0.5", None, once),
        ("ntc-0.5", Some("on"), twice),
    ] {
        let mut args = vec!["--profile", profile];
        args.extend(flag.iter().flat_map(|f| ["--hi-bilinear", *f]));
        let o = plan(&args);
        assert!(o.status.success() && text(&o).contains(want), "{args:?}: {}", text(&o));
    }
    let o = plan(&["--profile", "nbc-0.1", "--hi-bilinear", "on"]);
    assert!(
        !o.status.success() && text(&o).contains("--hi-bilinear belongs to the NTC"),
        "{}",
        text(&o)
    );
    let o = nmat(&[
        "encode",
        s,
        "-o",
        out.to_str().unwrap(),
        "--codec",
        "jpeg",
        "--hi-bilinear",
        "off",
    ]);
    assert!(
        !o.status.success() && text(&o).contains("--hi-bilinear belongs to the neural codec"),
        "{}",
        text(&o)
    );
    assert!(!out.exists(), "nothing written");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--layout`: a packed `ntc-0.2` file of a 384² material has two layouts; `--dry-run` shows
/// both, `--layout trial` says what each way measured and which it kept, a forced way runs no
/// trial and is the trial's file where the trial kept it, and the default is one more bit per
/// latent first, without a trial.
#[test]
fn the_layout_trial_is_shown_and_can_be_skipped() {
    let dir = temp_dir("layout-trial");
    let src = dir.join("src");
    // A size whose two ways differ (at 512², and at 160² and below, the solved layout's grids
    // stay far under the memory factor, so both ways take the bit and there is no trial); the
    // smallest such, since each encode polishes its latents at the cost of many decodes.
    write_maps(&src, 192);
    let s = src.to_str().unwrap();
    let out = |name: &str| dir.join(name).to_str().unwrap().to_string();
    // Unpolished: the polish is the larger part of such a short encode, and the layouts' choice
    // with it is the encoder test's (`the_layout_trial_keeps_the_way_whose_short_training…`).
    let encode = |name: &str, extra: &[&str]| {
        let o = out(name);
        let args = ["encode", s, "-o", &o, "--profile", "ntc-0.2", "--steps", "40"];
        nmat(&[&args[..], &["--polish-sweeps", "0"], extra].concat())
    };
    let o = encode("plan.nmat", &["--dry-run"]);
    assert!(
        o.status.success()
            && text(&o).contains("or, the grids' resolution first")
            && text(&o).contains("level 0 (mips 0,1,2): Nearest4[0] + Bilinear[1] + Bilinear[0]"),
        "{}",
        text(&o)
    );
    let o = encode("trial.nmat", &["--layout", "trial"]);
    let said = text(&o);
    assert!(o.status.success(), "{said}");
    let line =
        said.lines().find(|l| l.starts_with("layout trial")).unwrap_or_else(|| panic!("{said}"));
    let kept = if line.ends_with("kept one more bit per latent first") {
        "bits-first"
    } else {
        assert!(line.ends_with("kept the grids' resolution first"), "{line}");
        "resolution-first"
    };
    let o = encode("forced.nmat", &["--layout", kept]);
    assert!(o.status.success() && !text(&o).contains("layout trial"), "{}", text(&o));
    let same =
        std::fs::read(out("trial.nmat")).unwrap() == std::fs::read(out("forced.nmat")).unwrap();
    assert!(same, "{kept}: the trial's file differs from the way it kept");
    let o = encode("default.nmat", &[]);
    assert!(o.status.success() && !text(&o).contains("layout trial"), "{}", text(&o));
    let bits_first = if kept == "bits-first" {
        out("forced.nmat")
    } else {
        assert!(encode("bits.nmat", &["--layout", "bits-first"]).status.success());
        out("bits.nmat")
    };
    let same = std::fs::read(out("default.nmat")).unwrap() == std::fs::read(bits_first).unwrap();
    assert!(same, "the default file is not the bits-first layout's");
    let o = encode("fixed.nmat", &["--fixed-rate", "--layout", "bits-first"]);
    assert!(!o.status.success() && text(&o).contains("cannot be used with"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bench_train_reports_every_kernel_row_and_refuses_bad_options() {
    let dir = temp_dir("bench-train");
    write_maps(&dir, 32);
    let d = dir.to_str().unwrap();
    let o = nmat(&["bench-train", d, "--steps", "3", "--runs", "1", "--threads", "1,2"]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    let kernels: Vec<_> =
        nmat_encode::TrainKernel::ALL.into_iter().filter(|k| k.is_available()).collect();
    for k in &kernels {
        for t in [1, 2] {
            let row = format!("| {} | {t} |", k.name());
            assert!(out.contains(&row), "missing row {row}:\n{out}");
        }
    }
    assert!(
        out.contains("f32 FMA peak") && out.contains("(90 % joint, 10 % quantization-aware)"),
        "{out}"
    );
    let o = nmat(
        &["bench-train", d, "--steps", "3", "--runs", "1", "--threads", "1"]
            .into_iter()
            .chain(["--phases", "80,5"])
            .collect::<Vec<_>>(),
    );
    assert!(text(&o).contains("(80 % joint, 5 % quantization-aware)"), "{}", text(&o));
    for (args, says) in [
        (vec!["--phases", "90"], "--phases [90]: give JOINT,QAT"),
        (vec!["--phases", "90,20"], "--phases [90, 20]: give JOINT,QAT"),
        (vec!["--kernel", "sse9"], "--kernel sse9: unknown"),
        (vec!["--steps", "0"], "must be at least 1"),
        (vec!["--threads", "1,0"], "--threads 0: must be between 1 and"),
        (vec!["--threads", "100000"], "--threads 100000: must be between 1 and"),
    ] {
        let mut all = vec!["bench-train", d];
        all.extend(args);
        let o = nmat(&all);
        assert!(!o.status.success(), "{all:?} succeeded");
        assert!(text(&o).contains(says), "{all:?}: {}", text(&o));
    }
    for k in nmat_encode::TrainKernel::ALL.into_iter().filter(|k| !k.is_available()) {
        let o = nmat(&["bench-train", d, "--kernel", k.name()]);
        assert!(text(&o).contains("this CPU cannot run it"), "{}", text(&o));
    }
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let o = nmat(&["bench-train", empty.to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("no image maps found"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `nmat bench --gpu` prints the GPU table where the binary has the `gpu` feature and says how to
/// get it where it has not; either way no CPU rows. `--kernel` measures one kernel only, and
/// needs `--gpu`.
#[test]
fn bench_gpu_prints_the_gpu_table_or_says_how_to_build_it() {
    let dir = temp_dir("bench-gpu");
    let o = nmat(&["demo", "-o", dir.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let file = dir.join("demo.nmat");
    let o = nmat(&["bench", file.to_str().unwrap(), "--gpu", "--runs", "1", "--region", "16"]);
    let out = text(&o);
    if out.contains("built without GPU support") {
        assert!(!o.status.success() && out.contains("--features gpu"), "{out}");
    } else {
        assert!(o.status.success(), "{out}");
        let rows = [
            "| region 16×16 of mip 0, all",
            "| whole chain, 9 mips |",
            "random requests",
            "| nmat_sample trilinear, 16×16 samples × 8 decodes",
            "| nmat_sample trilinear (module_for the material), 16×16 samples × 8 decodes",
            "| BC transcode of the region 16×16: 4 textures (BC1, BC5, BC4), decode and encode |",
            "| BC transcode of the region 16×16: 4 textures (BC7), decode and encode |",
            "BC transcode of the same region and textures (BC1, BC5, BC4) on the CPU (",
            "BC transcode of the same region and textures (BC7) on the CPU (",
        ];
        for row in rows {
            assert!(out.contains(row), "missing {row}:\n{out}");
        }
        assert!(out.contains("G i32 multiply-add/s") && out.contains("upload"), "{out}");
        // --kernel: every row through that kernel, none for the others.
        let fixture =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/ntc_rgb_64.nmat");
        let f = fixture.to_str().unwrap();
        let o = nmat(&["bench", f, "--gpu", "--kernel", "i32", "--runs", "1", "--region", "8"]);
        let out = text(&o);
        assert!(o.status.success(), "{out}");
        assert!(
            out.contains("kernel: tiled i32, ") && out.contains("asked for with --kernel"),
            "{out}"
        );
        assert!(out.contains("| region 8×8, tiled i32 kernel: layers only"), "{out}");
        assert!(!out.contains("kernel |") && !out.contains("tiled dot4"), "other kernels:\n{out}");
    }
    assert!(!out.contains("peak multiply-add rate"), "CPU rows with --gpu:\n{out}");
    let o = nmat(&["bench", file.to_str().unwrap(), "--kernel", "i32"]);
    assert!(!o.status.success() && text(&o).contains("--gpu"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Whether `o` is a `--gpu` command's refusal by a binary built without the `gpu` feature (then
/// it says how to build one, and `dir` is removed): the test has nothing more to check.
fn built_without_gpu(o: &std::process::Output, dir: &Path) -> bool {
    let out = text(o);
    if !out.contains("built without GPU support") {
        return false;
    }
    assert!(!o.status.success() && out.contains("--features gpu"), "{out}");
    std::fs::remove_dir_all(dir).unwrap();
    true
}

/// `nmat walk --gpu` walks through the GPU's tile cache too, frame for frame with the same tiles
/// as the CPU's, where the binary has the `gpu` feature; says how to get it where it has not.
#[test]
fn walk_gpu_counts_the_tiles_the_cpu_counts_or_says_how_to_build_it() {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures");
    let (neural, jpeg) =
        (fixtures.join("ntc_pbr10_96x80_clamp.nmat"), fixtures.join("jpeg/pattern_420_37x21.nmat"));
    let dir = temp_dir("walk-gpu");
    let csv = dir.join("walk.csv");
    let o = nmat(&[
        "walk",
        neural.to_str().unwrap(),
        jpeg.to_str().unwrap(),
        "--size",
        "96x54",
        "--frames",
        "4",
        "--threads",
        "1",
        "--csv",
        csv.to_str().unwrap(),
        "--gpu",
    ]);
    let out = text(&o);
    if built_without_gpu(&o, &dir) {
        return;
    }
    assert!(o.status.success(), "{out}");
    assert!(out.contains("| yes | GPU | 4 |") && out.contains("| no | GPU | 4 |"), "{out}");
    // The GPU line names, per material, what decodes its new tiles.
    let (_, tiles) = out.split_once("tiles decoded by: ").unwrap();
    let (tiles, _) = tiles.split_once(" |").unwrap();
    let tiles: Vec<&str> = tiles.split(", ").collect();
    let kernels =
        ["reference", "unrolled i32", "unrolled dot4", "tiled i32", "tiled dot4", "matrix"];
    assert!(tiles.len() == 2 && kernels.contains(&tiles[0]) && tiles[1] == "JPEG", "{out}");
    let rows = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<Vec<&str>> = rows.lines().skip(1).map(|r| r.split(',').collect()).collect();
    assert_eq!(rows.len(), 16, "4 frames × (CPU, GPU) × (mips, no mips)");
    // Per frame and setting: marked, hits, decoded, decoded texels, evicted, overflowed and
    // resolve misses of the GPU equal the CPU's (this walk's coordinates pick the same texels).
    for cpu in rows.iter().filter(|r| r[1] == "1") {
        let gpu = rows.iter().find(|r| r[1] == "GPU" && r[0] == cpu[0] && r[2] == cpu[2]).unwrap();
        assert_eq!(gpu[3..10], cpu[3..10], "frame {} (mips {})", cpu[2], cpu[0]);
        let frame_ms = gpu[13].parse::<f64>().unwrap();
        assert!(frame_ms > 0.0);
        // Timed between GPU timestamps, the frame's three stages are timed apart and add up.
        if out.contains("GPU timestamps") {
            let stages: f64 = gpu[10..13].iter().map(|v| v.parse::<f64>().unwrap()).sum();
            assert!((stages - frame_ms).abs() <= 1e-3 * frame_ms + 1e-6, "{gpu:?}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs `nmat COMMAND FIXTURE -o DIR EXTRA…` with `--gpu` into `dir/gpuK` and with `cpu_flags`
/// into `dir/cpuK`; checks that the GPU run says how long opening the device and the upload took
/// and names its kernel (`kernel`), and that both runs wrote the same files byte for byte.
/// Returns their names, or `None` where the binary has no `gpu` feature (`dir` is then removed).
fn gpu_and_cpu_files(
    dir: &Path,
    k: usize,
    (command, name, extra): (&str, &str, &[&str]),
    cpu_flags: &[&str],
    kernel: &str,
) -> Option<Vec<String>> {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures");
    let (cpu_dir, gpu_dir) = (dir.join(format!("cpu{k}")), dir.join(format!("gpu{k}")));
    let f = fixtures.join(name);
    let f = f.to_str().unwrap();
    let (gpu_out, cpu_out) = (gpu_dir.to_str().unwrap(), cpu_dir.to_str().unwrap());
    let args = |out| [&[command, f, "-o", out], extra].concat();
    let o = nmat(&[args(gpu_out), vec!["--gpu"]].concat());
    if built_without_gpu(&o, dir) {
        return None;
    }
    assert!(o.status.success(), "{}", text(&o));
    // The fixed cost apart: opening the device, and the upload with the kernel it chose.
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("device opened in ") && err.contains(kernel), "{err}");
    let o = nmat(&[args(cpu_out), cpu_flags.to_vec()].concat());
    assert!(o.status.success(), "{}", text(&o));
    let names = files_in(&cpu_dir);
    assert_eq!(files_in(&gpu_dir), names, "{name} {extra:?}");
    for file in &names {
        let (c, g) = (std::fs::read(cpu_dir.join(file)), std::fs::read(gpu_dir.join(file)));
        assert!(c.unwrap() == g.unwrap(), "{name} {extra:?}: {file} differs");
    }
    Some(names)
}

/// `nmat transcode --gpu` writes the CPU's files byte for byte (every texture of a mip from one
/// decode on the GPU), for a neural and a JPEG material, and for the neural one in BC7 (a texture
/// for each of its six maps: albedo, normal, roughness, height, ao, metallic), where the binary
/// has the `gpu` feature.
#[test]
fn transcode_gpu_writes_the_cpus_files() {
    let dir = temp_dir("transcode-gpu");
    let cases: [(&str, &[&str], usize); 3] = [
        ("ntc_pbr10_96x80_clamp.nmat", &[], 6),
        ("jpeg/pattern_420_37x21.nmat", &[], 1),
        ("ntc_pbr10_96x80_clamp.nmat", &["--format", "bc7"], 6),
    ];
    for (k, (name, extra, files)) in cases.iter().enumerate() {
        let kernel = if k == 1 { "the JPEG kernel decodes it" } else { "kernel decodes it" };
        let Some(names) = gpu_and_cpu_files(&dir, k, ("transcode", name, extra), &[], kernel)
        else {
            return;
        };
        assert_eq!(names.len(), *files, "{name} {extra:?}: {names:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `nmat decode --gpu` writes the integer decoder's files byte for byte (every mip submitted
/// before the first is written), for a neural and a JPEG material, every mip and one, where the
/// binary has the `gpu` feature.
#[test]
fn decode_gpu_writes_the_cpus_files() {
    let dir = temp_dir("decode-gpu");
    let cases: [(&str, &[&str]); 3] = [
        ("ntc_pbr10_96x80_clamp.nmat", &["--mip", "all"]),
        ("ntc_pbr10_96x80_clamp.nmat", &["--mip", "2"]),
        ("jpeg/pattern_420_37x21.nmat", &["--mip", "all"]),
    ];
    for (k, (name, extra)) in cases.iter().enumerate() {
        let what = ("decode", *name, *extra);
        let Some(names) = gpu_and_cpu_files(&dir, k, what, &["--int"], "kernel decodes it") else {
            return;
        };
        assert!(!names.is_empty(), "{name} {extra:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `decode --gpu --kernel-choices FILE`: the file is written after the upload (this adapter's
/// first line; a software adapter measures nothing), and read in a later run, where the choice it
/// lists for the material's network decides the kernel (still probed: the files equal the
/// integer decoder's) and nothing is written back; a file that is not kernel choices (a material,
/// a line without a tab) is refused naming it (and the line), left as it was, nothing decoded;
/// a missing folder is refused before anything runs. Where the binary has the `gpu` feature.
#[test]
fn decode_gpu_keeps_kernel_choices_in_a_file() {
    let dir = temp_dir("kernel-choices");
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures");
    let fixture = fixture.join("ntc_pbr10_96x80_clamp.nmat");
    let f = fixture.to_str().unwrap();
    let choices = dir.join("choices.txt");
    let run = |out: &str, file: &Path| {
        let out = dir.join(out);
        let args = ["decode", f, "-o", out.to_str().unwrap(), "--gpu", "--kernel-choices"];
        nmat(&[&args[..], &[file.to_str().unwrap()]].concat())
    };
    let o = run("first", &choices);
    if built_without_gpu(&o, &dir) {
        return;
    }
    assert!(o.status.success(), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(err.contains(&format!("kernel choices written to {}", choices.display())), "{err}");
    let written = std::fs::read_to_string(&choices).unwrap();
    assert!(written.starts_with("nmat-wgpu kernel choices "), "{written}");
    // A choice for the fixture's network: a kernel other than the one chosen without it.
    let bytes = std::fs::read(&fixture).unwrap();
    let m = nmat_core::Container::parse(&bytes).unwrap();
    let nmat_core::Body::Neural(n) = m.body() else { panic!("a neural fixture") };
    let widths: Vec<(usize, usize)> =
        n.mlp().layers().iter().map(|l| (l.inputs(), l.outputs())).collect();
    let (id, name) = if err.contains("the tiled i32 kernel") {
        ("reference", "reference")
    } else {
        ("i32", "tiled i32")
    };
    let listed = format!("{written}{id}\t{widths:?} {}\n", m.channel_count());
    std::fs::write(&choices, &listed).unwrap();
    let o = run("second", &choices);
    assert!(o.status.success(), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("1 kernel choice(s) taken from"), "{err}");
    assert!(err.contains(&format!("the {name} kernel decodes it")), "{err}");
    assert!(!err.contains("written to"), "{err}");
    assert_eq!(std::fs::read_to_string(&choices).unwrap(), listed);
    let int = dir.join("int");
    let o = nmat(&["decode", f, "-o", int.to_str().unwrap(), "--int"]);
    assert!(o.status.success(), "{}", text(&o));
    let names = files_in(&int);
    assert_eq!(files_in(&dir.join("second")), names);
    for file in &names {
        let got = std::fs::read(dir.join("second").join(file)).unwrap();
        assert!(got == std::fs::read(int.join(file)).unwrap(), "{file} differs");
    }
    // Not kernel choices: refused, left as they were, nothing decoded.
    let bad = dir.join("bad.txt");
    let bad_text = format!("{written}i32 without a tab\n");
    std::fs::write(&bad, &bad_text).unwrap();
    for (k, (file, why)) in
        [(fixture.as_path(), "UTF-8"), (bad.as_path(), "line 2")].iter().enumerate()
    {
        let before = std::fs::read(file).unwrap();
        let o = run(&format!("refused{k}"), file);
        let out = text(&o);
        assert!(!o.status.success() && out.contains("--kernel-choices"), "{out}");
        assert!(out.contains(&file.display().to_string()) && out.contains(why), "{out}");
        assert_eq!(std::fs::read(file).unwrap(), before, "{}", file.display());
        assert!(!dir.join(format!("refused{k}")).exists(), "{out}");
    }
    let o = run("nofolder", &dir.join("missing").join("choices.txt"));
    assert!(!o.status.success() && text(&o).contains("no folder"), "{}", text(&o));
    assert!(!dir.join("missing").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn fuzz_regression_inputs_of_the_cli_target_never_panic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/regressions/cli");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).expect("fuzz/regressions/cli exists") {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "md") {
            nmat_cli::exercise_untrusted(&std::fs::read(&path).unwrap());
            count += 1;
        }
    }
    assert!(count >= 3, "regression inputs missing in {}", dir.display());
}

/// The pixels of the uncompressed 24- or 32-bit TGA `nvdecompress` writes (BGR(A); the 15 alpha
/// bits its header declares make the `image` crate refuse it), as a lookup of RGB by (x, y).
fn read_nvtt_tga(bytes: &[u8]) -> impl Fn(u32, u32) -> [u8; 3] + '_ {
    assert!(bytes[2] == 2 && (bytes[16] == 24 || bytes[16] == 32), "an uncompressed TGA");
    let step = usize::from(bytes[16] / 8);
    let (w, h) =
        (u16::from_le_bytes([bytes[12], bytes[13]]), u16::from_le_bytes([bytes[14], bytes[15]]));
    let top_down = bytes[17] & 0x20 != 0;
    let data = &bytes[18 + usize::from(bytes[0])..];
    move |x, y| {
        let row = if top_down { y } else { u32::from(h) - 1 - y };
        let at = step * (row as usize * usize::from(w) + x as usize);
        [data[at + 2], data[at + 1], data[at]]
    }
}

/// The blocks of every mip of `texture`, from the core's API: what a transcoded file must hold.
fn blocks_of(m: &nmat_core::Material<'_>, texture: &nmat_core::bc::BcTexture) -> Vec<Vec<u8>> {
    let d = nmat_core::Decoder::new(m);
    (0..m.mip_count())
        .map(|mip| {
            let region = nmat_core::BlockRegion::mip(m, mip);
            let row = region.width as usize * texture.format.block_bytes();
            let mut out = vec![0u8; row * region.height as usize];
            d.transcode_blocks(m, texture, mip, region, &mut out, row).unwrap();
            out
        })
        .collect()
}

/// `nmat transcode` writes one file per texture of the layout, and independent readers accept
/// them: the `ktx2` crate (header, every level's bytes, and the data format descriptor equal to
/// the one it generates itself for the format), `ddsfile` (DXGI format, size, mip count, data),
/// and NVIDIA's `nvdecompress` on the DDS files, whose pixels for BC1/BC4/BC5 are within one
/// code of the core's decoder (NVTT rounds interpolated values down, the core to nearest).
#[test]
fn transcode_writes_ktx2_and_dds_that_independent_readers_accept() {
    use nmat_cli::transcode::{Choice, file_name, plan};
    use nmat_core::bc::BcFormat;
    let fixture =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/ntc_pbr10_96x80_clamp.nmat");
    let bytes = std::fs::read(&fixture).unwrap();
    let m = nmat_core::Container::parse(&bytes).unwrap();
    let dir = temp_dir("transcode");
    let ktx_dir = dir.join("ktx2");
    let o = nmat(&["transcode", fixture.to_str().unwrap(), "-o", ktx_dir.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let auto = plan(&m, &Choice::default());
    let names: Vec<String> =
        auto.iter().map(|n| file_name(n, nmat_cli::transcode::Container::Ktx2)).collect();
    assert_eq!(
        names,
        [
            "albedo.bc1.ktx2",
            "normal.bc5.ktx2",
            "roughness.bc4.ktx2",
            "height.bc4.ktx2",
            "ao.bc4.ktx2",
            "metallic.bc4.ktx2",
        ]
    );
    assert_eq!(files_in(&ktx_dir), {
        let mut sorted = names.clone();
        sorted.sort();
        sorted
    });
    for (named, name) in auto.iter().zip(&names) {
        let file = std::fs::read(ktx_dir.join(name)).unwrap();
        let r = ktx2::Reader::new(&file[..]).unwrap_or_else(|e| panic!("{name}: {e:?}"));
        let h = r.header();
        let format = match (named.texture.format, named.texture.srgb) {
            (BcFormat::Bc1, true) => ktx2::Format::BC1_RGB_SRGB_BLOCK,
            (BcFormat::Bc1, false) => ktx2::Format::BC1_RGB_UNORM_BLOCK,
            (BcFormat::Bc4, _) => ktx2::Format::BC4_UNORM_BLOCK,
            (BcFormat::Bc5, _) => ktx2::Format::BC5_UNORM_BLOCK,
            other => panic!("{other:?} not in the auto layout"),
        };
        assert_eq!(h.format, Some(format), "{name}");
        assert_eq!((h.pixel_width, h.pixel_height, h.type_size), (96, 80, 1), "{name}");
        assert_eq!(h.level_count, m.mip_count(), "{name}");
        assert_eq!(h.supercompression_scheme, None);
        let levels: Vec<Vec<u8>> = r.levels().map(|l| l.data.to_vec()).collect();
        assert_eq!(levels, blocks_of(&m, &named.texture), "{name}");
        let (want, _) = ktx2::dfd::Basic::from_format(format).unwrap();
        assert_eq!(r.basic_dfd(), Some(&want), "{name}: data format descriptor");
        assert_eq!(r.writer().map(|w| w.starts_with("nmat ")), Some(true));
    }

    // DDS, with the albedo in BC7 and everything else in BC1 (gray maps as gray BC1): DX10 for
    // the sRGB ones, the legacy FourCC DXT1 for the others; and the auto layout (ATI1, ATI2).
    let dds_dir = dir.join("dds");
    let o = nmat(&[
        "transcode",
        fixture.to_str().unwrap(),
        "-o",
        dds_dir.to_str().unwrap(),
        "--container",
        "dds",
        "--format",
        "bc1",
        "--as",
        "albedo=bc7",
        "--threads",
        "1",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let auto_dir = dir.join("dds-auto");
    let o = nmat(&[
        "transcode",
        fixture.to_str().unwrap(),
        "-o",
        auto_dir.to_str().unwrap(),
        "--container",
        "dds",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let choice = Choice {
        all: Some(BcFormat::Bc1),
        by_semantic: vec![(nmat_core::Semantic::ALBEDO, BcFormat::Bc7Rgb)],
    };
    let textures = plan(&m, &choice);
    assert_eq!(textures.len(), 6);
    assert_eq!(textures[0].texture.format, BcFormat::Bc7Rgb);
    assert!(textures[1..].iter().all(|t| t.texture.format == BcFormat::Bc1));
    let nvdecompress = Command::new("nvdecompress").output().is_ok();
    if !nvdecompress {
        eprintln!(
            "nvdecompress not found (apt-get install libnvtt-bin): DDS files not decoded by it"
        );
    }
    let all = textures.iter().map(|t| (t, &dds_dir)).chain(auto.iter().map(|t| (t, &auto_dir)));
    for (named, dir) in all {
        let name = file_name(named, nmat_cli::transcode::Container::Dds);
        let path = dir.join(&name);
        let dds = ddsfile::Dds::read(&mut &std::fs::read(&path).unwrap()[..]).unwrap();
        let t = named.texture;
        let dxgi = match (t.format, t.srgb) {
            (BcFormat::Bc7Rgb, true) => Some(ddsfile::DxgiFormat::BC7_UNorm_sRGB),
            (BcFormat::Bc1, true) => Some(ddsfile::DxgiFormat::BC1_UNorm_sRGB),
            _ => None,
        };
        assert_eq!(dds.header10.as_ref().map(|h| h.dxgi_format), dxgi, "{name}");
        let fourcc = |code: &[u8; 4]| Some(ddsfile::FourCC(u32::from_le_bytes(*code)));
        let want_fourcc = match (t.format, t.srgb) {
            (BcFormat::Bc1, false) => fourcc(b"DXT1"),
            (BcFormat::Bc4, _) => fourcc(b"ATI1"),
            (BcFormat::Bc5, _) => fourcc(b"ATI2"),
            _ => fourcc(b"DX10"),
        };
        assert_eq!(dds.header.spf.fourcc, want_fourcc, "{name}");
        assert_eq!((dds.get_width(), dds.get_height()), (96, 80));
        assert_eq!(dds.get_num_mipmap_levels(), m.mip_count());
        let blocks = blocks_of(&m, &t);
        // (`Dds::get_data` estimates the chain's length as a quarter per level, short of the
        // real length for sizes that are not powers of two: the whole data is compared.)
        assert!(dds.data == blocks.concat(), "{name}: the data differ");
        // NVTT 2 misreads DX10 files: the legacy ones only.
        if nvdecompress && dxgi.is_none() {
            let o = Command::new("nvdecompress").arg(&path).output().unwrap();
            assert!(o.status.success(), "nvdecompress {name}: {}", text(&o));
            let tga = path.with_extension("tga");
            let tga_bytes = std::fs::read(&tga).unwrap();
            let img = read_nvtt_tga(&tga_bytes);
            std::fs::remove_file(&tga).unwrap();
            let mut worst = 0;
            let bb = t.format.block_bytes();
            for (k, block) in blocks[0].chunks(bb).enumerate() {
                let (bx, by) = (k as u32 % 24, k as u32 / 24);
                for (i, px) in nmat_core::bc::decode_block(t.format, block).iter().enumerate() {
                    let theirs = img(4 * bx + i as u32 % 4, 4 * by + i as u32 / 4);
                    for c in 0..t.format.components() {
                        worst = worst.max(px[c].abs_diff(theirs[c]));
                    }
                }
            }
            assert!(worst <= 1, "{name}: nvdecompress differs by {worst} codes");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Bad `nmat transcode` arguments name the argument and write nothing; existing files are kept
/// unless --force.
#[test]
fn transcode_refuses_bad_arguments_and_keeps_existing_files() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/ntc_rgb_64.nmat");
    let f = fixture.to_str().unwrap();
    let dir = temp_dir("transcode-bad");
    let out = dir.join("out");
    let o_dir = out.to_str().unwrap();
    for (args, needle) in [
        (vec!["--as", "albedo"], "--as albedo: expected ROLE=FORMAT"),
        (vec!["--as", "skin=bc1"], "unknown role \"skin\""),
        (vec!["--as", "albedo=bc3"], "the format must be bc1, bc4, bc5 or bc7"),
        (vec!["--as", "albedo=auto"], "the format must be bc1, bc4, bc5 or bc7"),
        (vec!["--format", "bc6"], "bc6"),
        (vec!["--threads", "0"], "--threads 0"),
    ] {
        let mut all = vec!["transcode", f, "-o", o_dir];
        all.extend(args);
        let o = nmat(&all);
        assert!(!o.status.success(), "{all:?}");
        assert!(text(&o).contains(needle), "{all:?}: {}", text(&o));
        assert!(!out.exists(), "{all:?} wrote {}", out.display());
    }
    let not_nmat = dir.join("x.png");
    std::fs::write(&not_nmat, b"\x89PNG\r\n\x1a\n").unwrap();
    let o = nmat(&["transcode", not_nmat.to_str().unwrap(), "-o", o_dir]);
    assert!(text(&o).contains("not a .nmat file (PNG signature)"), "{}", text(&o));
    // An existing file of the same name: refused, kept; replaced with --force.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("albedo.bc1.ktx2"), b"mine").unwrap();
    let o = nmat(&["transcode", f, "-o", o_dir]);
    assert!(!o.status.success() && text(&o).contains("already exist"), "{}", text(&o));
    assert_eq!(std::fs::read(out.join("albedo.bc1.ktx2")).unwrap(), b"mine");
    assert_eq!(files_in(&out), ["albedo.bc1.ktx2"]);
    let o = nmat(&["transcode", f, "-o", o_dir, "--force"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(std::fs::read(out.join("albedo.bc1.ktx2")).unwrap().starts_with(b"\xABKTX 20"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn index_turns_a_baseline_jpeg_into_a_material_every_command_reads() {
    let dir = temp_dir("index");
    let (w, h) = (40u32, 24u32);
    let pixels: Vec<u8> = (0..w * h * 3).map(|i| ((i * 7 + i / 120 * 13) % 251) as u8).collect();
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 85)
        .encode(&pixels, w, h, image::ExtendedColorType::Rgb8)
        .unwrap();
    let input = dir.join("photo.jpg");
    std::fs::write(&input, &jpeg).unwrap();
    let out = dir.join("photo.nmat");
    let o = nmat(&["index", input.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        text(&o).contains("40×24 YCbCr") && text(&o).contains("bits per pixel"),
        "{}",
        text(&o)
    );
    // Packed by default (the index rebuilt when the file is opened); --fixed-rate keeps it, and
    // unpacking the packed file gives exactly that file.
    let o = nmat(&["info", out.to_str().unwrap()]);
    let info = text(&o);
    assert!(info.contains("format 2.2") && info.contains("indexed JPEG maps"), "{info}");
    assert!(info.contains("rebuilt when opened"), "{info}");
    let fixed = dir.join("fixed.nmat");
    let o =
        nmat(&["index", input.to_str().unwrap(), "-o", fixed.to_str().unwrap(), "--fixed-rate"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&nmat(&["info", fixed.to_str().unwrap()])).contains("format 2.1"));
    let unpacked = dir.join("unpacked.nmat");
    let o = nmat(&["unpack", out.to_str().unwrap(), "-o", unpacked.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(std::fs::read(&unpacked).unwrap() == std::fs::read(&fixed).unwrap());
    assert!(std::fs::metadata(&out).unwrap().len() < std::fs::metadata(&fixed).unwrap().len());
    let decoded = dir.join("decoded");
    let o = nmat(&["decode", out.to_str().unwrap(), "-o", decoded.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    // One RGB image named after the JPEG.
    assert_eq!(files_in(&decoded), ["photo.png"]);
    let png = image::open(decoded.join("photo.png")).unwrap();
    assert_eq!((png.width(), png.height(), png.color()), (w, h, image::ColorType::Rgb8));
    // Nothing replaces the source, and a file that is not a JPEG is named.
    let o = nmat(&["index", input.to_str().unwrap(), "-o", input.to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("is one of the input"), "{}", text(&o));
    assert_eq!(std::fs::read(&input).unwrap(), jpeg);
    let o = nmat(&["index", out.to_str().unwrap(), "-o", dir.join("x.nmat").to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("not a JPEG file"), "{}", text(&o));
    assert!(!dir.join("x.nmat").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn encode_codec_jpeg_writes_a_material_decode_and_eval_read() {
    let dir = temp_dir("encode-jpeg");
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    write_maps(&src, 64);
    let (s, file) = (src.to_str().unwrap(), dir.join("bricks.nmat"));
    let f = file.to_str().unwrap();
    let o = nmat(&["encode", s, "-o", f, "--codec", "jpeg", "--quality", "70"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("jpeg quality 70 (4 JPEG maps)"), "{}", text(&o));
    let o = nmat(&["info", f]);
    assert!(
        text(&o).contains("indexed JPEG maps") && text(&o).contains("MCU 16×16"),
        "{}",
        text(&o)
    );
    let o = nmat(&["eval", f, "--ref", s]);
    assert!(o.status.success() && text(&o).contains("overall: PSNR"), "{}", text(&o));
    let decoded = dir.join("decoded");
    let o = nmat(&["decode", f, "-o", decoded.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(files_in(&decoded), files_in(&src));
    // A rate: the highest quality within it.
    let o = nmat(&["encode", s, "-o", f, "--codec", "jpeg", "--bppc", "1.5"]);
    let overall = text(&o).lines().find(|l| l.starts_with("overall:")).map(str::to_string);
    let bppc: f64 = overall
        .as_deref()
        .and_then(|l| l.split(", ").last())
        .and_then(|l| l.split(' ').next())
        .and_then(|b| b.parse().ok())
        .unwrap_or_else(|| panic!("{}", text(&o)));
    assert!(bppc <= 1.5, "{}", text(&o));
    // Options of the other codec are refused by name, and nothing is written.
    let other = dir.join("other.nmat");
    let g = other.to_str().unwrap();
    for (args, needle) in [
        (vec!["--codec", "jpeg", "--profile", "ntc-0.2"], "--profile belongs to the neural codec"),
        (vec!["--codec", "jpeg", "--steps", "10"], "--steps belongs to the neural codec"),
        (vec!["--codec", "jpeg", "--legacy-lod"], "--legacy-lod belongs to the neural codec"),
        (vec!["--codec", "jpeg", "--effort", "max"], "--effort belongs to the neural codec"),
        (vec!["--codec", "jpeg", "--layout", "bits-first"], "--layout belongs to the neural codec"),
        (
            vec!["--codec", "jpeg", "--output-margin", "0.02"],
            "--output-margin belongs to the neural codec",
        ),
        (vec!["--subsampling", "4:4:4"], "--subsampling belongs to the JPEG codec"),
        (vec!["--quality", "50"], "--quality 50: sets the JPEG codec's quality"),
        (vec!["--codec", "jpeg", "--quality", "0"], "'--quality"),
    ] {
        let o = nmat(&[&["encode", s, "-o", g][..], &args].concat());
        assert!(!o.status.success() && text(&o).contains(needle), "{args:?}: {}", text(&o));
        assert!(!other.exists());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn walk_resolves_every_frame_like_direct_decoding_and_writes_its_rows() {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures");
    let (neural, jpeg) =
        (fixtures.join("ntc_pbr10_96x80_clamp.nmat"), fixtures.join("jpeg/pattern_420_37x21.nmat"));
    let dir = temp_dir("walk");
    let (csv, png) = (dir.join("walk.csv"), dir.join("last.png"));
    let o = nmat(&[
        "walk",
        neural.to_str().unwrap(),
        jpeg.to_str().unwrap(),
        "--size",
        "96x54",
        "--frames",
        "4",
        "--threads",
        "1,2",
        "--direct-every",
        "1",
        "--csv",
        csv.to_str().unwrap(),
        "--image",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    // Two settings (with and without mips) × two thread counts, one summary row each.
    assert_eq!(
        text(&o).lines().filter(|l| l.starts_with("| yes |") || l.starts_with("| no |")).count(),
        4
    );
    let rows = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<&str> = rows.lines().skip(1).collect();
    assert_eq!(rows.len(), 16, "4 frames × 4 settings");
    // Every frame was also decoded directly, and the cache gave the same image.
    assert!(rows.iter().all(|r| r.ends_with(",true")), "{rows:?}");
    // Frame 0 decodes every tile it marks; later frames of the same walk keep some.
    let field = |r: &str, i: usize| r.split(',').nth(i).unwrap().parse::<u64>().unwrap();
    assert!(rows.iter().filter(|r| field(r, 2) == 0).all(|r| field(r, 3) == field(r, 5)));
    assert!(rows.iter().any(|r| field(r, 2) > 0 && field(r, 4) > 0));
    let image = image::open(&png).unwrap();
    assert_eq!((image.width(), image.height()), (96, 54));
    // Bad arguments are refused with a message, before any work.
    for bad in [["--size", "96"], ["--frames", "0"], ["--threads", "0"]] {
        let o = nmat(&["walk", neural.to_str().unwrap(), bad[0], bad[1]]);
        assert!(!o.status.success() && !text(&o).is_empty(), "{bad:?}");
    }
    let o = nmat(&["walk", fixtures.join("strip_1x37.nmat").to_str().unwrap(), "--size", "8x8"]);
    assert!(!o.status.success(), "{}", text(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Runs `nmat args` and kills it if it runs past `seconds` (the old `nmat index FIFO` waited
/// forever): `None` then.
fn nmat_within(args: &[&str], seconds: u64) -> Option<Output> {
    let mut child = Command::new(env!("CARGO_BIN_EXE_nmat"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run nmat");
    let start = std::time::Instant::now();
    while start.elapsed().as_secs() < seconds {
        if child.try_wait().unwrap().is_some() {
            return Some(child.wait_with_output().unwrap());
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let _ = child.kill();
    let _ = child.wait();
    None
}

/// Every output of `nmat walk` is checked before the walk, every size against `--max-memory`
/// before anything is allocated, and `--threads` is capped like the other commands'.
#[test]
fn walk_checks_its_outputs_sizes_and_threads_before_it_starts() {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures");
    let dir = temp_dir("walk-hostile");
    let input = dir.join("v.nmat");
    std::fs::copy(fixtures.join("ntc_pbr10_96x80_clamp.nmat"), &input).unwrap();
    let original = std::fs::read(&input).unwrap();
    let v = input.to_str().unwrap();
    let missing = dir.join("nodir/x.csv");
    let small = ["--size", "16x8", "--frames", "1", "--threads", "1"];
    let cases: [(Vec<&str>, &str); 8] = [
        (vec!["--image", v], "--image"),
        (vec!["--csv", v], "--csv"),
        (vec!["--csv", missing.to_str().unwrap()], "folder"),
        (vec!["--csv", dir.to_str().unwrap()], "is a directory"),
        (vec!["--tiles", "20000000"], "--tiles"),
        (vec!["--tiles", "1000000000000"], "--tiles"),
        (vec!["--size", "16384x16384"], "--size"),
        (vec!["--threads", "3000"], "--threads 3000: must be between 1 and"),
    ];
    for (extra, needle) in cases {
        // The small walk, but for the option under test.
        let mut args = vec!["walk", v];
        for pair in small.chunks(2) {
            if !extra.contains(&pair[0]) {
                args.extend(pair);
            }
        }
        args.extend(&extra);
        let o = nmat_within(&args, 20).unwrap_or_else(|| panic!("{args:?} ran past 20 s"));
        assert!(!o.status.success(), "{args:?} succeeded: {}", text(&o));
        assert!(text(&o).contains(needle), "{args:?}: {}", text(&o));
        assert!(!text(&o).contains("memory allocation"), "{args:?}: {}", text(&o));
        // Refused before the walk: no table row was printed.
        assert!(!text(&o).contains("| yes |"), "{args:?} walked: {}", text(&o));
    }
    assert_eq!(std::fs::read(&input).unwrap(), original, "the input material was replaced");
    assert!(!missing.parent().unwrap().exists());
    // The budget names the option and the limit; a larger budget lets the same walk run.
    let o = nmat(&["walk", v, "--size", "64x32", "--frames", "1", "--max-memory", "1M"]);
    assert!(text(&o).contains("more than the 1.0 MiB allowed"), "{}", text(&o));
    let o = nmat(&["walk", v, "--size", "64x32", "--frames", "1", "--tiles", "64"]);
    assert!(o.status.success(), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `nmat index` reads its JPEG through the one bounded, regular-file-only reader.
#[test]
fn index_reads_only_regular_files_within_the_memory_budget() {
    let dir = temp_dir("index-hostile");
    let out = dir.join("y.nmat");
    let o = out.to_str().unwrap();
    if cfg!(unix) {
        let r = nmat_within(&["index", "/dev/zero", "-o", o], 20).expect("index /dev/zero ran on");
        assert!(!r.status.success() && text(&r).contains("not a regular file"), "{}", text(&r));
        let fifo = dir.join("pipe.jpg");
        if Command::new("mkfifo").arg(&fifo).status().is_ok_and(|s| s.success()) {
            let r = nmat_within(&["index", fifo.to_str().unwrap(), "-o", o], 20)
                .expect("index of a FIFO waited for a writer");
            assert!(!r.status.success() && text(&r).contains("not a regular file"), "{}", text(&r));
        }
    }
    let jpeg = dir.join("photo.jpg");
    // Noise: a JPEG of several KiB.
    let pixels: Vec<u8> =
        (0u32..64 * 64 * 3).map(|i| (i.wrapping_mul(2654435761) >> 24) as u8).collect();
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90)
        .encode(&pixels, 64, 64, image::ExtendedColorType::Rgb8)
        .unwrap();
    std::fs::write(&jpeg, &bytes).unwrap();
    let r = nmat(&["index", jpeg.to_str().unwrap(), "-o", o, "--max-memory", "0K"]);
    assert!(text(&r).contains("must be above 0"), "{}", text(&r));
    let r = nmat(&["index", jpeg.to_str().unwrap(), "-o", o, "--max-memory", "1K"]);
    assert!(!r.status.success(), "{}", text(&r));
    assert!(bytes.len() > 1024 && text(&r).contains("bytes, more than the 1024 bytes allowed"));
    assert!(text(&r).contains("--max-memory") && !out.exists(), "{}", text(&r));
    let r = nmat(&["index", jpeg.to_str().unwrap(), "-o", o]);
    assert!(r.status.success(), "{}", text(&r));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `eval` and `bench` compare channels with the reference maps of the same role only: other maps
/// of the same size and channel count are refused (or, with --force, compared after a warning).
#[test]
fn reference_maps_of_other_roles_are_refused_unless_forced() {
    let dir = temp_dir("ref-roles");
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    write_maps(&src, 16);
    let file = dir.join("m.nmat");
    let f = file.to_str().unwrap();
    let o = nmat(&["encode", src.to_str().unwrap(), "-o", f, "--steps", "2"]);
    assert!(o.status.success(), "{}", text(&o));
    // The same four files, but the roughness map now named as a metallic map: 8 channels of the
    // same size as the material's, one of them another map.
    let other = dir.join("other");
    std::fs::create_dir_all(&other).unwrap();
    for name in ["bricks_albedo.png", "bricks_normal.png", "bricks_height.png"] {
        std::fs::copy(src.join(name), other.join(name)).unwrap();
    }
    std::fs::copy(src.join("bricks_roughness.png"), other.join("bricks_metallic.png")).unwrap();
    let r = other.to_str().unwrap();
    let o = nmat(&["eval", f, "--ref", r]);
    assert!(!o.status.success(), "eval compared other maps: {}", text(&o));
    assert!(text(&o).contains("no roughness map") && text(&o).contains("--force"), "{}", text(&o));
    let o = nmat(&["bench", f, "--ref", r, "--region", "8", "--runs", "1"]);
    assert!(!o.status.success() && text(&o).contains("no roughness map"), "{}", text(&o));
    let o = nmat(&["eval", f, "--ref", r, "--force"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        text(&o).contains("warning") && text(&o).contains("channel 6 is roughness"),
        "{}",
        text(&o)
    );
    // The source maps themselves, and a folder with more maps than the material's, are fine.
    std::fs::copy(src.join("bricks_roughness.png"), src.join("bricks_metallic.png")).unwrap();
    let o = nmat(&["eval", f, "--ref", src.to_str().unwrap()]);
    assert!(o.status.success() && !text(&o).contains("warning"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Names a file carries are printed and used as file names only once made safe, and a damaged
/// optional section is ignored with the same warning by every command.
#[test]
fn names_from_files_are_made_safe_and_damaged_optional_sections_are_ignored() {
    let dir = temp_dir("names");
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    write_maps(&src, 16);
    let file = dir.join("m.nmat");
    let o = nmat(&["encode", src.to_str().unwrap(), "-o", file.to_str().unwrap(), "--steps", "2"]);
    assert!(o.status.success(), "{}", text(&o));
    let bytes = std::fs::read(&file).unwrap();
    let at = |s: &[u8]| s.windows(17).position(|w| w == b"bricks_albedo.png").unwrap();
    // A terminal escape, a NUL and a path out of the folder, in the 17 bytes of the name.
    let hostile = with_source_maps(&bytes, |s| {
        let n = at(s);
        s[n..n + 17].copy_from_slice(b"\x1b[31m\0..\\evil.png");
    });
    let path = dir.join("hostile.nmat");
    std::fs::write(&path, hostile).unwrap();
    let p = path.to_str().unwrap();
    let o = nmat(&["info", p]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(!text(&o).contains('\x1b') && !text(&o).contains('\0'), "{:?}", text(&o));
    assert!(text(&o).contains("_[31m_.._evil.png"), "{}", text(&o));
    let out = dir.join("out");
    let o = nmat(&["decode", p, "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(!text(&o).contains('\x1b'), "{:?}", text(&o));
    assert!(files_in(&out).contains(&"_[31m_.._evil.png".to_string()), "{:?}", files_in(&out));
    assert_eq!(files_in(&dir), ["hostile.nmat", "m.nmat", "out", "src"]);

    // Damaged sections: no maps listed; a map beyond the channels.
    let record = |s: &[u8]| at(s) - 8;
    let damaged = [
        ("zero", with_source_maps(&bytes, |s| s[2..4].fill(0)), "lists no maps"),
        (
            "beyond",
            with_source_maps(&bytes, |s| s[record(s) + 2] = 200),
            "channels 200..203 are not within",
        ),
    ];
    for (name, patched, why) in damaged {
        let path = dir.join(format!("{name}.nmat"));
        std::fs::write(&path, patched).unwrap();
        let p = path.to_str().unwrap();
        let out = dir.join(format!("{name}-out"));
        let tc = dir.join(format!("{name}-tc"));
        let runs = [
            vec!["info", p],
            vec!["decode", p, "-o", out.to_str().unwrap()],
            vec!["transcode", p, "-o", tc.to_str().unwrap()],
            vec!["eval", p, "--ref", src.to_str().unwrap()],
        ];
        for args in runs {
            let o = nmat(&args);
            assert!(o.status.success(), "{args:?}: {}", text(&o));
            let warning = "SOURCE_MAPS section (optional";
            assert_eq!(text(&o).matches(warning).count(), 1, "{args:?}: {}", text(&o));
            assert!(text(&o).contains(why) && text(&o).contains("ignored"), "{}", text(&o));
        }
        // Maps named after the channels.
        assert!(files_in(&out).contains(&"albedo.png".to_string()), "{:?}", files_in(&out));
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `nmat transcode` is all-or-nothing like `decode`, refuses conflicting `--as`, says what is
/// wrong with `-o`, keeps to `--max-memory`, and leaves no staging folder when killed.
#[test]
fn transcode_is_all_or_nothing_and_checks_its_arguments() {
    let fixture =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/ntc_pbr10_96x80_clamp.nmat");
    let f = fixture.to_str().unwrap();
    let dir = temp_dir("transcode-aon");
    let out = dir.join("out");
    let o_dir = out.to_str().unwrap();
    let o = nmat(&["transcode", f, "-o", o_dir, "--as", "albedo=bc1", "--as", "albedo=bc7"]);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("--as albedo=bc7: albedo maps were already given bc1"));
    let o = nmat(&["transcode", f, "-o", o_dir, "--as", "albedo=bc7", "--as", "albedo=bc7"]);
    assert!(o.status.success(), "the same format twice: {}", text(&o));
    let names = files_in(&out);
    assert!(names.len() >= 3, "{names:?}");
    // A regular file as -o.
    let plain = dir.join("plain");
    std::fs::write(&plain, b"x").unwrap();
    let o = nmat(&["transcode", f, "-o", plain.to_str().unwrap()]);
    assert!(text(&o).contains("is a file, not a folder"), "{}", text(&o));
    // --force with a folder planted at one output name: nothing is replaced, not even the files
    // moved in before the folder was met.
    let (first, last) = (&names[0], &names[names.len() - 1]);
    std::fs::write(out.join(first), b"mine").unwrap();
    std::fs::remove_file(out.join(last)).unwrap();
    std::fs::create_dir(out.join(last)).unwrap();
    let o = nmat(&["transcode", f, "-o", o_dir, "--as", "albedo=bc7", "--force"]);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("is a folder") && text(&o).contains("nothing was written"));
    assert_eq!(std::fs::read(out.join(first)).unwrap(), b"mine");
    assert!(!files_in(&out).iter().any(|n| n.starts_with(".nmat")), "{:?}", files_in(&out));
    // The budget.
    let small = dir.join("small");
    let o = nmat(&["transcode", f, "-o", small.to_str().unwrap(), "--max-memory", "1K"]);
    assert!(text(&o).contains("--max-memory") && !small.exists(), "{}", text(&o));
    // A staging folder of a process that no longer runs (killed with SIGKILL) is removed by the
    // next write into the folder.
    if Path::new("/proc/self").exists() {
        let stale = out.join(".nmat-decode-999999999-0123456789abcdef");
        std::fs::create_dir(&stale).unwrap();
        std::fs::write(stale.join("half.ktx2"), b"half").unwrap();
        std::fs::remove_dir(out.join(last)).unwrap();
        let o = nmat(&["transcode", f, "-o", o_dir, "--force"]);
        assert!(o.status.success(), "{}", text(&o));
        assert!(!stale.exists(), "an abandoned staging folder was kept");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// SIGTERM during a long transcode removes its staging folder and the output folder it made.
#[cfg(unix)]
#[test]
fn a_killed_transcode_leaves_nothing_behind() {
    let dir = temp_dir("transcode-kill");
    // A generated material of 2048², whose BC7 chain takes seconds.
    let cfg = nmat_tests::generate::FixtureConfig::ntc("kill", 7, 2048, 2048, 3);
    let file = dir.join("m.nmat");
    std::fs::write(&file, nmat_tests::generate::generate(&cfg).to_bytes().unwrap()).unwrap();
    let f = file.to_str().unwrap();
    let out = dir.join("out");
    let child = Command::new(env!("CARGO_BIN_EXE_nmat"))
        .args(["transcode", f, "-o", out.to_str().unwrap(), "--format", "bc7", "--threads", "1"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for the staging folder, then kill.
    let start = std::time::Instant::now();
    let staging = || {
        std::fs::read_dir(&out)
            .map(|d| d.flatten().any(|e| e.file_name().to_string_lossy().starts_with(".nmat")))
            .unwrap_or(false)
    };
    while !staging() && start.elapsed().as_secs() < 60 {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    assert!(staging(), "no staging folder appeared");
    let killed = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    assert!(killed.success());
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!out.exists(), "left behind: {:?}", std::fs::read_dir(&out).map(|d| d.count()));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Without a GPU (lavapipe), `nmat bench`'s GPU row decodes the bench's region only and says so,
/// instead of the whole mip 0 (minutes on a software rasterizer).
#[test]
fn bench_gpu_row_on_a_software_adapter_decodes_the_region_only() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/ntc_rgb_64.nmat");
    let o = nmat(&["bench", fixture.to_str().unwrap(), "--region", "8", "--runs", "1"]);
    assert!(o.status.success(), "{}", text(&o));
    let out = text(&o);
    // One file alone has nothing to compare with (`nmat bench A B`: the next test).
    assert!(!out.contains("same run"), "{out}");
    let gpu_row = out.lines().find(|l| l.trim_start().starts_with("GPU")).expect("a GPU line");
    if gpu_row.contains("not measured") || gpu_row.contains("no adapter") {
        return; // a build without the `gpu` feature, or no adapter at all
    }
    if gpu_row.contains("software rasterizer") {
        assert!(gpu_row.contains("region 8×8 only"), "{gpu_row}");
    } else {
        assert!(gpu_row.contains("whole mip 0"), "{gpu_row}");
    }
}

/// `nmat bench --cpu-only` leaves the GPU row out whatever the build (a `gpu` build would add it,
/// minutes on a software adapter), and is refused together with `--gpu`.
#[test]
fn bench_cpu_only_leaves_out_the_gpu_row() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/ntc_rgb_64.nmat");
    let f = fixture.to_str().unwrap();
    let o = nmat(&["bench", f, "--region", "8", "--runs", "1", "--cpu-only"]);
    assert!(o.status.success(), "{}", text(&o));
    let out = text(&o);
    let gpu_lines: Vec<&str> = out.lines().filter(|l| l.trim_start().starts_with("GPU")).collect();
    assert_eq!(gpu_lines, ["  GPU: not measured (--cpu-only)"], "{out}");
    assert!(out.contains("peak multiply-add rate"), "no CPU rows:\n{out}");
    let o = nmat(&["bench", f, "--gpu", "--cpu-only"]);
    assert!(!o.status.success() && text(&o).contains("--cpu-only"), "{}", text(&o));
}

/// `nmat bench A B`: after the tables, B's decode speed against A's, timed in alternation (the
/// machine's drift meets both): one line per file after the first, three positive ratios
/// (region; random access one call a texel and a batch a call).
#[test]
fn bench_of_several_files_compares_them_in_one_run() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/ntc_rgb_64.nmat");
    let f = fixture.to_str().unwrap();
    let o = nmat(&["bench", f, f, "--region", "8", "--runs", "3"]);
    assert!(o.status.success(), "{}", text(&o));
    let out = text(&o);
    let at = out.find("same run, runs alternated with").expect("a same-run section");
    let ratios: Vec<f64> = out[at..]
        .lines()
        .nth(1)
        .unwrap()
        .split_whitespace()
        .filter_map(|w| w.strip_suffix('×')?.parse().ok())
        .collect();
    assert_eq!(ratios.len(), 3, "{}", &out[at..]);
    assert!(ratios.iter().all(|r| r.is_finite() && *r > 0.0), "{ratios:?}");
}

/// `nmat build`: a manifest of three materials built, kept when nothing changed, rebuilt where a
/// map changed or with --force; the outputs byte-identical whether built whole or in shards;
/// one failing material does not stop the others; bad manifests refused before any work.
#[test]
fn build_caches_shards_and_isolates_failures() {
    let dir = temp_dir("build");
    for (name, size) in [("brick", 16), ("wall", 24), ("floor", 32)] {
        let d = dir.join("textures").join(name);
        std::fs::create_dir_all(&d).unwrap();
        write_maps(&d, size);
    }
    let manifest = |out: &str, extra: &str| {
        let path = dir.join(format!("{out}.toml"));
        std::fs::write(
            &path,
            format!(
                "[defaults]\nprofile = \"ntc-0.5\"\nsteps = 10\nmemory_factor = 1.2\n{extra}\n[[material]]\n\
                 input = \"textures/*\"\noutput = \"{out}/{{name}}.nmat\"\n"
            ),
        )
        .unwrap();
        path
    };
    let whole = manifest("whole", "");
    let build = |m: &Path, extra: &[&str]| {
        let mut args = vec!["build", m.to_str().unwrap()];
        args.extend_from_slice(extra);
        nmat(&args)
    };
    let o = build(&whole, &[]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("3 built, 0 up to date, 0 failed"), "{}", text(&o));
    let csv = std::fs::read_to_string(dir.join("whole.summary.csv")).unwrap();
    assert_eq!(csv.lines().count(), 4, "{csv}");
    assert!(csv.lines().skip(1).all(|l| l.contains(",built,")), "{csv}");
    // The summary's numbers are those `nmat eval` gives the file.
    let eval = text(&nmat(&[
        "eval",
        dir.join("whole/brick.nmat").to_str().unwrap(),
        "--ref",
        dir.join("textures/brick").to_str().unwrap(),
    ]));
    let psnr = eval.split("overall: PSNR ").nth(1).unwrap().split(' ').next().unwrap();
    let brick = csv.lines().find(|l| l.starts_with("\"brick\"")).unwrap();
    assert!(brick.contains(&format!(",{psnr},")), "{brick} vs eval {psnr}");

    // Nothing changed: nothing rebuilt (--report adds each material's HTML report). One map
    // changed: that material only. --force: all.
    // The build's page beside the summary links every report and plots brick (its output and
    // the anchors' rows for "brick"), with the summary's numbers.
    let anchors = dir.join("anchors.csv");
    std::fs::write(&anchors, "brick,avif,quantizer40,0.3,30\nbrick,avif,quantizer20,0.9,36\n")
        .unwrap();
    let o = build(&whole, &["--report", "--anchors", anchors.to_str().unwrap()]);
    assert!(text(&o).contains("0 built, 3 up to date"), "{}", text(&o));
    let page = std::fs::read_to_string(dir.join("whole.summary.html")).unwrap();
    assert_eq!(page.matches("<tr class=\"material\">").count(), 3, "{page}");
    for name in ["brick", "wall", "floor"] {
        let html = std::fs::read_to_string(dir.join(format!("whole/{name}.nmat.html"))).unwrap();
        assert!(html.contains("class=\"psnr\"") && html.contains("data:image/png"), "{name}");
        assert!(page.contains(&format!("href=\"whole/{name}.nmat.html\"")), "{name}: {page}");
    }
    let fields: Vec<&str> = brick.split(',').collect();
    let number = |i: usize| fields[i].parse::<f64>().unwrap();
    let (bppc, chain_psnr) = (number(5), number(6));
    assert_eq!(page.matches("<svg class=\"rate-quality\"").count(), 1, "{page}");
    let point =
        format!("data-series=\"nmat\" data-bppc=\"{bppc:.4}\" data-psnr=\"{chain_psnr:.2}\"");
    assert!(page.contains(&point), "{point}: {page}");
    assert_eq!(page.matches("data-series=\"avif\"").count(), 2, "{page}");
    write_maps(&dir.join("textures/wall"), 20);
    let o = build(&whole, &["--jobs", "1"]);
    assert!(text(&o).contains("1 built, 2 up to date"), "{}", text(&o));
    assert!(text(&o).contains("wall: built"), "{}", text(&o));
    // A build interrupted after writing an output but before its record: that one again.
    std::fs::remove_file(dir.join("whole/floor.nmat.build")).unwrap();
    let o = build(&whole, &[]);
    assert!(text(&o).contains("1 built, 2 up to date"), "{}", text(&o));
    assert!(text(&o).contains("floor: built"), "{}", text(&o));
    let o = build(&whole, &["--force", "--summary", dir.join("s.json").to_str().unwrap()]);
    assert!(text(&o).contains("3 built, 0 up to date"), "{}", text(&o));
    let json = std::fs::read_to_string(dir.join("s.json")).unwrap();
    assert_eq!(json.matches("\"status\": \"built\"").count(), 3, "{json}");

    // Three shards on "three machines" give the files of the whole build, byte for byte.
    let sharded = manifest("sharded", "");
    for k in ["1/3", "2/3", "3/3"] {
        let o = build(
            &sharded,
            &["--shard", k, "--summary", dir.join(format!("s{}.csv", &k[..1])).to_str().unwrap()],
        );
        assert!(o.status.success(), "{}", text(&o));
    }
    for name in ["brick", "wall", "floor"] {
        let a = std::fs::read(dir.join(format!("whole/{name}.nmat"))).unwrap();
        let b = std::fs::read(dir.join(format!("sharded/{name}.nmat"))).unwrap();
        assert!(a == b, "{name}: sharded build differs");
    }

    // Through an emitted build file, run by Ninja (installed by scripts/test.sh) and by Make:
    // the same files again.
    for (kind, tool, flag) in [("ninja", "ninja", "-f"), ("make", "make", "-f")] {
        let m = manifest(kind, "");
        let file = dir.join(format!("{kind}.build"));
        let o = build(&m, &["--emit", kind, "-o", file.to_str().unwrap()]);
        assert!(o.status.success(), "{}", text(&o));
        assert!(!dir.join(kind).exists(), "--emit built something");
        let edges = std::fs::read_to_string(&file).unwrap();
        assert!(edges.contains("--memory-factor' '1.2'"), "{edges}");
        // Run in the test's folder: Ninja keeps its log (.ninja_log) in the current one.
        let ran =
            Command::new(tool).args([flag, file.to_str().unwrap()]).current_dir(&dir).output();
        let Ok(ran) = ran else {
            eprintln!(
                "{tool} is not installed: the {kind} file is not run (scripts/test.sh installs it)"
            );
            continue;
        };
        assert!(ran.status.success(), "{kind}: {}", text(&ran));
        for name in ["brick", "wall", "floor"] {
            let a = std::fs::read(dir.join(format!("whole/{name}.nmat"))).unwrap();
            let b = std::fs::read(dir.join(format!("{kind}/{name}.nmat"))).unwrap();
            assert!(a == b, "{name}: the {kind} build differs");
        }
    }

    // A folder without maps fails; the others are built and the exit status says so.
    std::fs::create_dir_all(dir.join("textures/empty")).unwrap();
    let o = build(&manifest("failing", ""), &[]);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("3 built, 0 up to date, 1 failed"), "{}", text(&o));
    assert!(text(&o).contains("empty: FAILED"), "{}", text(&o));
    assert!(!dir.join("failing/empty.nmat").exists());
    std::fs::remove_dir(dir.join("textures/empty")).unwrap();

    // Refused before any work, naming the problem.
    let refused = |body: &str, needle: &str| {
        let path = dir.join("bad.toml");
        std::fs::write(&path, body).unwrap();
        let o = build(&path, &[]);
        assert!(!o.status.success() && text(&o).contains(needle), "{needle}: {}", text(&o));
        assert!(!dir.join("bad").exists(), "{needle}: work started");
    };
    let entry = |input: &str, output: &str| {
        format!("[[material]]\ninput = \"{input}\"\noutput = \"{output}\"\n")
    };
    refused(&entry("textures/missing", "bad/x.nmat"), "is not a folder");
    refused(&entry("nothing/*", "bad/{name}.nmat"), "nothing");
    refused(&entry("textures/x*", "bad/{name}.nmat"), "matches no folder");
    refused(&entry("textures/*", "bad/all.nmat"), "has no {name}");
    refused(
        &format!(
            "{}{}",
            entry("textures/brick", "bad/x.nmat"),
            entry("textures/wall", "bad/x.nmat")
        ),
        "both write",
    );
    refused(&entry("textures/*", "textures/{name}/out.nmat"), "inside the input folder");
    refused(
        "[defaults]\nprofil = \"ntc-0.2\"\n[[material]]\ninput = \"a\"\noutput = \"b\"\n",
        "profil",
    );
    refused("", "no [[material]]");
    let o = build(&whole, &["--shard", "3/2"]);
    assert!(!o.status.success() && text(&o).contains("--shard 3/2"), "{}", text(&o));
    let o = build(&whole, &["--emit", "ninja"]);
    assert!(!o.status.success() && text(&o).contains("--output"), "{}", text(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Standard base64 decoding (RFC 4648), independent of the report writer's encoder.
fn unbase64(s: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {c}"),
    };
    let mut out = Vec::new();
    for chunk in s.as_bytes().chunks(4) {
        let n =
            chunk.iter().filter(|&&c| c != b'=').fold(0u32, |n, &c| n << 6 | u32::from(value(c)));
        let pad = chunk.iter().filter(|&&c| c == b'=').count();
        let n = n << (6 * pad);
        out.extend_from_slice(&n.to_be_bytes()[1..4 - pad]);
    }
    out
}

/// `nmat eval --report` of two files of one source (neural and JPEG) with anchors: one HTML file
/// whose every picture decodes (source, decode and heat map for every map at every mip of each
/// file), whose numbers are those `nmat eval` prints, and whose plot puts every point where its
/// numbers say.
#[test]
fn eval_report_is_one_html_file_whose_pictures_and_numbers_hold() {
    let dir = temp_dir("report");
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    write_maps(&src, 40);
    let (file, jpeg) = (dir.join("m.nmat"), dir.join("j.nmat"));
    let o = nmat(&["encode", src.to_str().unwrap(), "-o", file.to_str().unwrap(), "--steps", "30"]);
    assert!(o.status.success(), "{}", text(&o));
    let o = nmat(&[
        "encode",
        src.to_str().unwrap(),
        "-o",
        jpeg.to_str().unwrap(),
        "--codec",
        "jpeg",
        "--quality",
        "80",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    // Two codecs' curves for this source ("src") and a row of another material, left out.
    let anchors = dir.join("anchors.csv");
    std::fs::write(
        &anchors,
        "material,codec,setting,bppc,psnr_db,seconds\n\
         src,jpegxl,q40,0.2500,30.000,1.0\nsrc,jpegxl@ntc-0.2,q60,0.5000,33.500,1.0\n\
         src,avif,quantizer40,0.2000,31.000,1.0\nother,avif,quantizer8,3.0000,50.000,1.0\n",
    )
    .unwrap();
    let report = dir.join("report.html");
    let eval_args = |extra: &[&str]| {
        let mut args = vec!["eval", file.to_str().unwrap(), jpeg.to_str().unwrap()];
        args.extend(["--ref", src.to_str().unwrap(), "--report", report.to_str().unwrap()]);
        args.extend(extra);
        args.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let args = eval_args(&["--anchors", anchors.to_str().unwrap()]);
    let o = nmat(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let eval = text(&o);
    assert!(o.status.success(), "{eval}");
    let html = std::fs::read_to_string(&report).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    // Self-contained: every picture is inline, nothing is fetched.
    assert!(!html.contains("src=\"http") && !html.contains("href="), "external reference");
    let sections: Vec<&str> = html.split("<section class=\"file\">").skip(1).collect();
    let evals: Vec<&str> = eval.split("== ").skip(1).collect();
    assert_eq!((sections.len(), evals.len()), (2, 2), "{eval}");
    let mut file_points = Vec::new();
    for (section, eval) in sections.iter().zip(&evals) {
        let images: Vec<&str> = section
            .split("src=\"data:image/png;base64,")
            .skip(1)
            .map(|r| r.split('"').next().unwrap())
            .collect();
        // 4 maps (albedo, normal, roughness, height) × 6 mips (40² … 1²) × source, decode, heat.
        assert_eq!(images.len(), 4 * 6 * 3);
        for (i, b64) in images.iter().enumerate() {
            let img = image::load_from_memory(&unbase64(b64))
                .unwrap_or_else(|e| panic!("image {i}: {e}"));
            let side = 40 >> (i / 3 % 6);
            assert_eq!((img.width(), img.height()), (side.max(1), side.max(1)), "image {i}");
        }
        // The numbers: eval's overall PSNR, SSIM and rate, and each map's chain PSNR.
        let overall = eval.lines().find(|l| l.starts_with("overall: PSNR ")).unwrap();
        let word_after = |key: &str| overall.split(key).nth(1).unwrap().split(' ').next().unwrap();
        let (psnr, ssim) = (word_after("PSNR "), word_after("SSIM "));
        let bppc = overall.split(", ").last().unwrap().split(' ').next().unwrap();
        for (class, value) in [("psnr", psnr), ("ssim", ssim), ("bppc", bppc)] {
            assert!(section.contains(&format!("class=\"{class}\">{value}<")), "{class} {value}");
        }
        file_points.push((bppc.to_string(), psnr.to_string()));
        let map_lines: Vec<&str> = eval.lines().filter(|l| l.starts_with("bricks_")).collect();
        assert_eq!(map_lines.len(), 4, "{eval}");
        for line in map_lines {
            let mut words = line.split_whitespace();
            let (name, chain) = (words.next().unwrap(), words.next().unwrap());
            let at = section
                .find(&format!("<h3 class=\"map\">{name}</h3>"))
                .unwrap_or_else(|| panic!("{name}"));
            assert!(section[at..].contains(&format!("class=\"map-psnr\">{chain}<")), "{name}");
        }
    }
    // The plot: one point per file and per anchor row of this material, with eval's numbers.
    let attr = |point: &str, name: &str| -> String {
        point.split(&format!("{name}=\"")).nth(1).unwrap().split('"').next().unwrap().to_string()
    };
    let points: Vec<(String, String, String, f64, f64)> = html
        .split("<circle class=\"point\"")
        .skip(1)
        .map(|p| {
            let at = |name| attr(p, name).parse::<f64>().unwrap();
            (attr(p, "data-series"), attr(p, "data-bppc"), attr(p, "data-psnr"), at("cx"), at("cy"))
        })
        .collect();
    let mut seen: Vec<(&str, &str, &str)> =
        points.iter().map(|(s, b, p, ..)| (s.as_str(), b.as_str(), p.as_str())).collect();
    seen.sort();
    let mut expected = vec![
        ("avif", "0.2000", "31.00"),
        ("jpegxl", "0.2500", "30.00"),
        ("jpegxl", "0.5000", "33.50"),
        ("nmat JPEG", file_points[1].0.as_str(), file_points[1].1.as_str()),
        ("nmat neural", file_points[0].0.as_str(), file_points[0].1.as_str()),
    ];
    expected.sort();
    assert_eq!(seen, expected);
    // Placed as the axes say: a larger rate further right, a higher PSNR further up.
    for a in &points {
        for b in &points {
            let (ra, rb) = (a.1.parse::<f64>().unwrap(), b.1.parse::<f64>().unwrap());
            let (qa, qb) = (a.2.parse::<f64>().unwrap(), b.2.parse::<f64>().unwrap());
            assert!(ra <= rb || a.3 > b.3, "x of {a:?} and {b:?}");
            assert!(qa <= qb || a.4 < b.4, "y of {a:?} and {b:?}");
        }
    }
    // Refused before any work: anchors of no row for this material, a malformed number, the
    // report over an input, anchors without a report.
    let refused = |args: &[&str], needle: &str| {
        let o = nmat(args);
        assert!(!o.status.success() && text(&o).contains(needle), "{needle}: {}", text(&o));
    };
    std::fs::write(&anchors, "other,avif,q,0.1,30\n").unwrap();
    let args = eval_args(&["--anchors", anchors.to_str().unwrap()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    refused(&args, "no row for material \"src\"");
    std::fs::write(&anchors, "src,avif,q,fast,30\n").unwrap();
    refused(&args, "line 1: bppc \"fast\"");
    let (file, src) = (file.to_str().unwrap(), src.to_str().unwrap());
    refused(&["eval", file, "--ref", src, "--report", file], "--report");
    refused(&["eval", file, "--ref", src, "--anchors", anchors.to_str().unwrap()], "--report");
    std::fs::remove_dir_all(&dir).unwrap();
}
