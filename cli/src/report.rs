//! `nmat eval --report`: one self-contained HTML file to look at a material — per map and mip the
//! source, the decode and an error heat map (PNG, inline), PSNR per map and mip, SSIM per map,
//! the rate on disk and in memory and the decode cost.

use crate::input::Stored;
use image::{ImageBuffer, Rgb};
use nmat_core::Material;
use nmat_encode::metrics::{ChainQuality, ssim_channel, unit_of};
use nmat_encode::texset::TextureSet;
use std::fmt::Write as _;
use std::path::Path;

/// The largest side of a picture in the report: a larger mip shows its top-left corner of this
/// size (the page stays a few megabytes for a 1024² material of five maps).
pub const MAX_SIDE: u32 = 512;
/// The error the heat map's brightest colour stands for (unit scale, the largest of a map's
/// channels at the texel); larger errors show the same colour.
pub const HEAT_FULL_SCALE: f32 = 0.1;

/// The report of `m` (read from `path`, stored as `stored`) against its source maps `set`, with
/// the quality `q` measured on them and the decode of each mip it was measured on (`decode_mip`'s
/// values, as `metrics::chain_quality_keeping` hands them over).
pub fn html(
    path: &Path,
    m: &Material<'_>,
    stored: Stored,
    set: &TextureSet,
    q: &ChainQuality,
    decoded: &[Vec<f32>],
) -> String {
    let title = escape(&path.display().to_string());
    let mut s = String::new();
    let _ = write!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>nmat report: {title}</title>\n\
         <style>body{{font-family:sans-serif;margin:1.5em}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}\
         img{{image-rendering:pixelated;max-width:256px;min-width:64px;border:1px solid #888}}\
         figure{{display:inline-block;margin:4px}}figcaption{{font-size:80%}}</style></head><body>\n\
         <h1>{title}</h1>\n"
    );
    let macs = m.neural().map_or(0, |n| n.mlp().macs_per_texel());
    let codec = if m.jpeg().is_some() {
        "indexed JPEG".to_string()
    } else {
        format!("neural, {macs} multiply-adds per texel")
    };
    let _ = writeln!(
        s,
        "<p id=\"summary\">{}×{}, {} mips, {} channels ({codec}); \
         <b>PSNR <span class=\"psnr\">{:.2}</span> dB</b> over all channels and mips, \
         SSIM <span class=\"ssim\">{:.4}</span> at mip 0, \
         <span class=\"bppc\">{:.4}</span> bits per pixel per channel on disk \
         ({:.4} in memory), {} bytes{}.</p>",
        m.width(),
        m.height(),
        m.mip_count(),
        m.channel_count(),
        q.psnr,
        q.ssim,
        m.bppc_of(stored.len),
        m.bppc(),
        stored.len,
        if stored.packed { " packed" } else { "" }
    );
    let _ = writeln!(
        s,
        "<p>Heat maps: the largest error of a map's channels at each texel, black 0 to white \
         {HEAT_FULL_SCALE} (unit scale) and above. Mips larger than {MAX_SIDE}² show their \
         top-left {MAX_SIDE}×{MAX_SIDE}.</p>"
    );
    let c = set.channel_count();
    let decoded: Vec<Vec<f32>> = decoded
        .iter()
        .map(|mip| mip.iter().enumerate().map(|(i, &d)| unit_of(m, i % c, d)).collect())
        .collect();
    for map in &set.maps {
        let chans: Vec<usize> =
            (map.first_channel..map.first_channel + map.channel_count).collect();
        let src0 = &set.mips[0];
        let ssim = chans
            .iter()
            .map(|&ch| ssim_channel(&src0.data, &decoded[0], src0.width, src0.height, c, ch))
            .sum::<f64>()
            / chans.len() as f64;
        let name = escape(&map.file_name);
        let _ = write!(
            s,
            "<h2 class=\"map\">{name}</h2>\n<p>whole chain: PSNR <span class=\"map-psnr\">{:.2}</span> dB, \
             SSIM at mip 0 <span class=\"map-ssim\">{ssim:.4}</span></p>\n<table><tr><th>mip</th>",
            q.psnr_of(&chans, None, set)
        );
        for mip in 0..set.mips.len() {
            let _ = write!(s, "<th>{mip}</th>");
        }
        s.push_str("</tr><tr><th>PSNR dB</th>");
        for mip in 0..set.mips.len() {
            let _ = write!(s, "<td>{:.2}</td>", q.psnr_of(&chans, Some(mip), set));
        }
        s.push_str("</tr></table>\n");
        for (mip, src) in set.mips.iter().enumerate() {
            let (w, h) = (src.width.min(MAX_SIDE), src.height.min(MAX_SIDE));
            let crop = if (w, h) != (src.width, src.height) { ", top-left crop" } else { "" };
            let _ = writeln!(
                s,
                "<div class=\"mip\"><h3>mip {mip}: {}×{}{crop}</h3>",
                src.width, src.height
            );
            let pick = |data: &[f32], x: u32, y: u32, k: usize| -> f32 {
                let ch = chans.get(k).or(chans.last()).copied().unwrap_or(0);
                data[(y * src.width + x) as usize * c + ch]
            };
            let picture = |f: &dyn Fn(u32, u32) -> [u8; 3]| png_data_uri(w, h, f);
            let to8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            // Gray maps as gray, two channels as R and G, three or more as RGB.
            let colour = |data: &[f32], x: u32, y: u32| -> [u8; 3] {
                match chans.len() {
                    1 => [to8(pick(data, x, y, 0)); 3],
                    2 => [to8(pick(data, x, y, 0)), to8(pick(data, x, y, 1)), 0],
                    _ => [0, 1, 2].map(|k| to8(pick(data, x, y, k))),
                }
            };
            let dec = &decoded[mip];
            let heat = |x: u32, y: u32| {
                let e = (0..chans.len())
                    .map(|k| (pick(dec, x, y, k) - pick(&src.data, x, y, k)).abs())
                    .fold(0.0f32, f32::max);
                heat_colour(e / HEAT_FULL_SCALE)
            };
            for (label, uri) in [
                ("source", picture(&|x, y| colour(&src.data, x, y))),
                ("decoded", picture(&|x, y| colour(dec, x, y))),
                ("error", picture(&heat)),
            ] {
                let _ = writeln!(
                    s,
                    "<figure><img class=\"{label}\" alt=\"{name} mip {mip} {label}\" src=\"{uri}\"><figcaption>{label}</figcaption></figure>"
                );
            }
            s.push_str("</div>\n");
        }
    }
    s.push_str("</body></html>\n");
    s
}

/// Black → red → yellow → white as `t` goes 0 → 1 (clamped).
fn heat_colour(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0) * 3.0;
    let part = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [part(t), part(t - 1.0), part(t - 2.0)]
}

fn png_data_uri(w: u32, h: u32, f: &dyn Fn(u32, u32) -> [u8; 3]) -> String {
    let img: ImageBuffer<Rgb<u8>, Vec<u8>> = ImageBuffer::from_fn(w, h, |x, y| Rgb(f(x, y)));
    let mut png = Vec::new();
    // Writing a PNG to memory cannot fail for a valid buffer; an empty picture otherwise.
    let _ = img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png);
    format!("data:image/png;base64,{}", base64(&png))
}

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc_4648_test_vectors() {
        for (raw, coded) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(raw.as_bytes()), coded);
        }
    }

    #[test]
    fn the_heat_scale_runs_black_red_yellow_white() {
        assert_eq!(heat_colour(0.0), [0, 0, 0]);
        assert_eq!(heat_colour(1.0 / 3.0), [255, 0, 0]);
        assert_eq!(heat_colour(2.0 / 3.0), [255, 255, 0]);
        assert_eq!(heat_colour(5.0), [255, 255, 255]);
    }
}
