//! What the CLI prints and writes: descriptions, quality tables, decoded maps, atomic files.

use nmat_core::{ChannelMask, Decoder, Material, SectionKind};
use nmat_encode::metrics::{ChainQuality, unit_of};
use nmat_encode::source_maps;
use nmat_encode::texset::{FileLayout, Role, SourceMap};
use nmat_encode::{ByteBudget, TextureSet};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so a reader
/// never sees a partial file and a failure leaves no output behind. The temporary file has an
/// unpredictable name and is created exclusively: a file or symlink planted under a name nmat
/// might pick is never opened, so it cannot redirect the write.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let context =
        |e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: {e}", path.display()));
    let (tmp, mut f) = create_exclusive(dir, &name).map_err(context)?;
    let result = (|| {
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(context)
}

/// Checks, before any long work, that [`write_atomic`] can write `path`: it is not a directory,
/// it is none of `inputs` (a source is never replaced), and its folder exists and accepts a new
/// file.
pub fn check_output(path: &Path, inputs: &[PathBuf]) -> Result<(), String> {
    let shown = path.display();
    if path.is_dir() {
        return Err(format!(
            "-o {shown}: is a directory; give a file name such as {shown}/material.nmat"
        ));
    }
    if let Ok(out) = path.canonicalize()
        && inputs.iter().any(|i| i.canonicalize().is_ok_and(|i| i == out))
    {
        return Err(format!("-o {shown}: is one of the input maps; choose another output name"));
    }
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !dir.is_dir() {
        return Err(format!("-o {shown}: folder {} does not exist", dir.display()));
    }
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let (tmp, f) = create_exclusive(dir, &name)
        .map_err(|e| format!("-o {shown}: cannot create a file in {}: {e}", dir.display()))?;
    drop(f);
    let _ = std::fs::remove_file(tmp);
    Ok(())
}

/// A new file `.NAME.tmp-RANDOM` in `dir`, created with `create_new` (fails on any existing
/// entry, symlinks included); a few names are tried.
fn create_exclusive(dir: &Path, name: &str) -> std::io::Result<(PathBuf, std::fs::File)> {
    use std::hash::{BuildHasher, Hasher};
    let mut last = None;
    for attempt in 0u32..16 {
        // RandomState is seeded from the OS's randomness once per process, then varied per call.
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u32(attempt);
        h.write_u32(std::process::id());
        let tmp = dir.join(format!(".{name}.tmp-{:016x}", h.finish()));
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last.unwrap_or_else(|| std::io::Error::other("no free temporary name")))
}

/// The SOURCE_MAPS section, if the file has a valid one.
pub fn source_maps(m: &Material<'_>) -> Option<Vec<SourceMap>> {
    let maps = source_maps::decode(
        m.optional_section(nmat_core::SectionKind(source_maps::SECTION_KIND))?,
    )?;
    let fits = maps
        .iter()
        .all(|s| s.channel_count >= 1 && s.first_channel + s.channel_count <= m.channel_count());
    fits.then_some(maps)
}

/// Maps by channel-name stem (`albedo.r/g/b` → one RGB map) for files without SOURCE_MAPS.
fn maps_from_names(m: &Material<'_>) -> Vec<SourceMap> {
    let mut maps: Vec<SourceMap> = Vec::new();
    for (c, ch) in m.channels().iter().enumerate() {
        let stem = ch.name.split('.').next().unwrap_or(ch.name);
        match maps.last_mut() {
            Some(last) if last.file_name == format!("{stem}.png") && last.channel_count < 4 => {
                last.channel_count += 1
            }
            _ => maps.push(SourceMap {
                role: Role::from_semantic(ch.semantic).unwrap_or(Role::Albedo),
                file_name: format!("{stem}.png"),
                layout: FileLayout::Gray,
                first_channel: c,
                channel_count: 1,
                gray_rgb: false,
                alpha_value: None,
                sixteen_bit: false,
            }),
        }
    }
    for map in &mut maps {
        map.layout = [FileLayout::Gray, FileLayout::GrayAlpha, FileLayout::Rgb, FileLayout::Rgba]
            [map.channel_count - 1];
    }
    maps
}

fn output_name(file_name: &str, mip: u32, single_mip0: bool) -> (String, image::ImageFormat) {
    let path = Path::new(file_name);
    let stem =
        path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "map".into());
    let ext =
        path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    // Lossy formats are not re-encoded lossily: they come back as PNG.
    let (ext, format) = match ext.as_str() {
        "tga" => ("tga", image::ImageFormat::Tga),
        "bmp" => ("bmp", image::ImageFormat::Bmp),
        "tif" | "tiff" => (if ext == "tif" { "tif" } else { "tiff" }, image::ImageFormat::Tiff),
        _ => ("png", image::ImageFormat::Png),
    };
    let name = if single_mip0 && mip == 0 {
        format!("{stem}.{ext}")
    } else {
        format!("{stem}_mip{mip}.{ext}")
    };
    (name, format)
}

/// The file names `write_maps` will write for `mips`, in order; an error if two maps would
/// share a name (a hostile or careless SOURCE_MAPS section) — found before anything is written.
pub fn output_files(m: &Material<'_>, mips: &[u32]) -> Result<Vec<String>, String> {
    let maps = source_maps(m).unwrap_or_else(|| maps_from_names(m));
    let single = mips == [0];
    let mut names: Vec<String> = Vec::new();
    for map in &maps {
        for &mip in mips {
            let (name, _) = output_name(&map.file_name, mip, single);
            if names.contains(&name) {
                return Err(format!(
                    "the file's source maps name {name} twice ({}); nothing was written",
                    map.file_name
                ));
            }
            names.push(name);
        }
    }
    Ok(names)
}

/// Decodes `mips` of every map and writes them into `dir` under their original names.
/// 8-bit codes of every channel of a whole mip, row-major, decoded elsewhere (the GPU).
pub type MipDecoder<'d> = dyn Fn(u32) -> Result<Vec<u8>, Box<dyn std::error::Error>> + 'd;

pub fn write_maps(
    m: &Material<'_>,
    dir: &Path,
    mips: &[u32],
    float: bool,
    batch: Option<&MipDecoder<'_>>,
) -> Result<Vec<PathBuf>, Box<dyn std::error::Error>> {
    let maps = source_maps(m).unwrap_or_else(|| maps_from_names(m));
    let channels = m.channel_count();
    let decoder = Decoder::new(m);
    let mut batched: Vec<Option<Vec<u8>>> = vec![None; m.mip_count() as usize];
    let mut written = Vec::new();
    let single = mips == [0];
    for map in &maps {
        for &mip in mips {
            let (w, h) = m.mip_size(mip);
            let comps = map.layout.components();
            // The batch decoder gives 8-bit codes: 16-bit maps come back at 8 bits from it.
            let sixteen = map.sixteen_bit && !float && batch.is_none();
            let all_codes: Option<&Vec<u8>> = match (batch, float) {
                (Some(decode), false) => {
                    let slot = &mut batched[mip as usize];
                    if slot.is_none() {
                        *slot = Some(decode(mip)?);
                    }
                    slot.as_ref()
                }
                _ => None,
            };
            let mut pixels: Vec<u16> = Vec::with_capacity((w * h) as usize * comps);
            let mask = ChannelMask((((1u32 << map.channel_count) - 1) << map.first_channel) as u16);
            let mut unit = [0f32; 16];
            let mut codes = [0u16; 16];
            let full = if sixteen { 65535.0 } else { 255.0 };
            for y in 0..h {
                for x in 0..w {
                    let (x, y) = (i64::from(x), i64::from(y));
                    if let Some(all) = all_codes {
                        let at =
                            (y as usize * w as usize + x as usize) * channels + map.first_channel;
                        for (k, u) in unit.iter_mut().enumerate().take(map.channel_count) {
                            *u = f32::from(all.get(at + k).copied().unwrap_or(0)) / 255.0;
                        }
                    } else if float {
                        m.decode_texel_unit(x, y, mip, mask, &mut unit)?;
                    } else if sixteen {
                        decoder.decode_texel_u16(m, x, y, mip, mask, &mut codes)?;
                        unit.iter_mut().zip(codes).for_each(|(u, c)| *u = f32::from(c) / 65535.0);
                    } else {
                        let mut c8 = [0u8; 16];
                        decoder.decode_texel_u8(m, x, y, mip, mask, &mut c8)?;
                        unit.iter_mut().zip(c8).for_each(|(u, c)| *u = f32::from(c) / 255.0);
                    }
                    let value = |k: usize| {
                        let u = unit_of(m, map.first_channel + k, unit[k]);
                        (u * full).round().clamp(0.0, full) as u16
                    };
                    let color = if map.gray_rgb {
                        vec![value(0); 3]
                    } else {
                        (0..map.channel_count.min(comps)).map(value).collect()
                    };
                    pixels.extend(color.iter().take(comps));
                    if let Some(a) = map.alpha_value {
                        pixels.push(if sixteen { u16::from(a) * 257 } else { u16::from(a) });
                    } else if map.gray_rgb && comps == 4 {
                        pixels.push(value(1));
                    }
                    while !pixels.len().is_multiple_of(comps) {
                        pixels.push(full as u16);
                    }
                }
            }
            let (name, format) = output_name(&map.file_name, mip, single);
            let image = to_image(w, h, map.layout, sixteen, pixels);
            let mut buffer = std::io::Cursor::new(Vec::new());
            // TGA and BMP have no 16-bit modes: those maps are written at 8 bits.
            let image = if sixteen
                && format != image::ImageFormat::Png
                && format != image::ImageFormat::Tiff
            {
                image::DynamicImage::from(image.to_rgba8())
            } else {
                image
            };
            image.write_to(&mut buffer, format)?;
            let path = dir.join(name);
            write_atomic(&path, buffer.get_ref())?;
            written.push(path);
        }
    }
    Ok(written)
}

fn to_image(w: u32, h: u32, layout: FileLayout, sixteen: bool, p: Vec<u16>) -> image::DynamicImage {
    use image::{DynamicImage as D, ImageBuffer};
    macro_rules! buf {
        ($px:ty, $data:expr) => {
            ImageBuffer::<$px, _>::from_raw(w, h, $data).unwrap_or_else(|| ImageBuffer::new(w, h))
        };
    }
    if sixteen {
        match layout {
            FileLayout::Gray => D::ImageLuma16(buf!(image::Luma<u16>, p)),
            FileLayout::GrayAlpha => D::ImageLumaA16(buf!(image::LumaA<u16>, p)),
            FileLayout::Rgb => D::ImageRgb16(buf!(image::Rgb<u16>, p)),
            FileLayout::Rgba => D::ImageRgba16(buf!(image::Rgba<u16>, p)),
        }
    } else {
        let p: Vec<u8> = p.into_iter().map(|v| v.min(255) as u8).collect();
        match layout {
            FileLayout::Gray => D::ImageLuma8(buf!(image::Luma<u8>, p)),
            FileLayout::GrayAlpha => D::ImageLumaA8(buf!(image::LumaA<u8>, p)),
            FileLayout::Rgb => D::ImageRgb8(buf!(image::Rgb<u8>, p)),
            FileLayout::Rgba => D::ImageRgba8(buf!(image::Rgba<u8>, p)),
        }
    }
}

/// `nmat info`.
pub fn describe(path: &Path, m: &Material<'_>) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}: .nmat format {}.{}, {} bytes",
        path.display(),
        m.version_major(),
        m.version_minor(),
        m.file_len()
    );
    let _ = writeln!(
        s,
        "size {}×{}, {} mips, {} channels, {:?} addressing, {:.4} bits per pixel per channel",
        m.width(),
        m.height(),
        m.mip_count(),
        m.channel_count(),
        m.address_mode(),
        m.bppc()
    );
    let _ = writeln!(s, "\nchannels:");
    for (i, c) in m.channels().iter().enumerate() {
        let role = Role::from_semantic(c.semantic).map_or("other", |r| r.name());
        let constant = if c.range_min == c.range_max {
            format!(" constant {}", c.range_min)
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "  {i:2} {:12} {role:10} {:?} [{}, {}]{constant}",
            c.name, c.color_space, c.range_min, c.range_max
        );
    }
    if let Some(maps) = source_maps(m) {
        s.push_str(&map_lines(&maps));
    }
    let _ = writeln!(s, "\nlatent grids:");
    for (i, g) in m.grids().iter().enumerate() {
        let _ = writeln!(
            s,
            "  {i:2} {:5}×{:<5} {:2} channels × {} bits  {:8} bytes",
            g.width(),
            g.height(),
            g.channels(),
            g.bits_per_latent(),
            g.packed_data().len()
        );
    }
    for (l, level) in m.levels().iter().enumerate() {
        let mips: Vec<String> = (0..m.mip_count())
            .filter(|&k| m.level_for_mip(k) == l)
            .map(|k| k.to_string())
            .collect();
        let terms: Vec<String> =
            level.terms.iter().map(|t| format!("{:?}{:?}", t.mode, t.grids.as_slice())).collect();
        let _ = writeln!(s, "  level {l} (mips {}): {}", mips.join(","), terms.join(" + "));
    }
    let mlp = m.mlp();
    let shape: Vec<String> =
        mlp.layers().iter().map(|l| format!("{}→{}", l.inputs(), l.outputs())).collect();
    let _ = writeln!(
        s,
        "\nMLP {} ({} MACs/texel), input Q.{}, {} PE frequencies, LOD input {}",
        shape.join(", "),
        mlp.macs_per_texel(),
        mlp.input_frac_bits(),
        mlp.pe_frequencies(),
        mlp.lod_input()
    );
    s.push_str(&budget_table(&file_budget(m), texel_channels(m)));
    s
}

pub fn texel_channels(m: &Material<'_>) -> f64 {
    f64::from(m.width()) * f64::from(m.height()) * m.channel_count() as f64
}

/// The source maps and the channels each one occupies, as `info` and `encode --dry-run` print them.
pub fn map_lines(maps: &[SourceMap]) -> String {
    let mut s = String::from("\nsource maps:\n");
    for map in maps {
        let _ = writeln!(
            s,
            "  {:28} {:9} {:?}{}{} → channels {}..{}",
            map.file_name,
            map.role.name(),
            map.layout,
            if map.sixteen_bit { " 16-bit" } else { "" },
            if map.gray_rgb { " (R = G = B, stored once)" } else { "" },
            map.first_channel,
            map.first_channel + map.channel_count - 1
        );
    }
    s
}

/// Where the bytes of a parsed file go, by section (header = header, section table, padding).
pub fn file_budget(m: &Material<'_>) -> ByteBudget {
    let len = |k| m.section_len(k).unwrap_or(0);
    let optional: usize = m.optional_sections().iter().map(|(_, d)| d.len()).sum();
    let b = ByteBudget {
        header: 0,
        material: len(SectionKind::MATERIAL),
        levels: len(SectionKind::LEVELS),
        network: len(SectionKind::MLP),
        latents: len(SectionKind::LATENTS),
        optional,
    };
    ByteBudget { header: m.file_len().saturating_sub(b.total()), ..b }
}

/// The byte budget as `info` and `encode --dry-run` print it: bytes, share of the file and bits
/// per pixel per channel of each part (`texel_channels` = width · height · channels of mip 0).
pub fn budget_table(b: &ByteBudget, texel_channels: f64) -> String {
    let total = b.total().max(1);
    let mut s = String::from("\nbyte budget:\n");
    for (name, bytes) in [
        ("latents", b.latents),
        ("network (int8 weights, row scales, biases)", b.network),
        ("grid and level records", b.levels),
        ("channel records", b.material),
        ("header and section table", b.header),
        ("source maps", b.optional),
        ("file", b.total()),
    ] {
        let _ = writeln!(
            s,
            "  {name:44} {bytes:9} bytes  {:5.1} %  {:.4} BPPC",
            100.0 * bytes as f64 / total as f64,
            bytes as f64 * 8.0 / texel_channels.max(1.0)
        );
    }
    s
}

/// The quality report of `encode`, `eval` and `demo`.
pub fn quality_table(set: &TextureSet, q: &ChainQuality, profile: Option<&str>) -> String {
    let mut s = String::new();
    if let Some(p) = profile {
        let _ = writeln!(s, "profile {p}");
    }
    let _ = writeln!(
        s,
        "{:28} {:>10} {}",
        "map",
        "chain dB",
        (0..set.mips.len()).map(|m| format!("{:>7}", format!("mip{m}"))).collect::<String>()
    );
    for map in &set.maps {
        let chans: Vec<usize> =
            (map.first_channel..map.first_channel + map.channel_count).collect();
        let _ = write!(s, "{:28} {:>10.2}", map.file_name, q.psnr_of(&chans, None, set));
        for m in 0..set.mips.len() {
            let _ = write!(s, "{:>7.2}", q.psnr_of(&chans, Some(m), set));
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(
        s,
        "overall: PSNR {:.2} dB over all channels and mips, SSIM {:.4} at mip 0, {:.4} bits per pixel per channel",
        q.psnr, q.ssim, q.bppc
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn a_planted_temporary_symlink_does_not_redirect_the_write() {
        let dir = std::env::temp_dir().join(format!("nmat-atomic-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let victim = dir.join("victim.txt");
        std::fs::write(&victim, b"keep me").unwrap();
        // The names an earlier version used (`.NAME.tmp-PID`) and a spread of guesses.
        for suffix in [std::process::id().to_string(), "0".into(), "1".into()] {
            let link = dir.join(format!(".out.nmat.tmp-{suffix}"));
            std::os::unix::fs::symlink(&victim, link).unwrap();
        }
        let out = dir.join("out.nmat");
        write_atomic(&out, b"new bytes").unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"keep me");
        assert!(std::fs::symlink_metadata(&out).unwrap().file_type().is_file());
        assert_eq!(std::fs::read(&out).unwrap(), b"new bytes");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failed_write_leaves_no_temporary_file() {
        let dir = std::env::temp_dir().join(format!("nmat-atomic-fail-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("out.nmat")).unwrap();
        // Renaming a file over a non-empty directory fails.
        std::fs::write(dir.join("out.nmat").join("x"), b"").unwrap();
        let err = write_atomic(&dir.join("out.nmat"), b"bytes").unwrap_err();
        assert!(err.to_string().contains("out.nmat"), "{err}");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 1, "only the directory remains");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
