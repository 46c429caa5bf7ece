//! `nmat eval --report`: one self-contained HTML file to look at materials — per file, map and mip
//! the source, the decode and an error heat map (PNG, inline), PSNR per map and mip, SSIM per map,
//! the rate on disk and in memory and the decode cost — and for several files of one source, a
//! rate–quality plot (SVG) with other codecs' points beside them.

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

/// The start of a page titled `title` (escaped here), up to its heading: the styles both pages
/// share and `css`.
fn head(title: &str, css: &str) -> String {
    let title = escape(title);
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}</title>\n\
         <style>body{{font-family:sans-serif;margin:1.5em}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}{css}</style></head><body>\n\
         <h1>{title}</h1>\n"
    )
}

/// The HTML page: a title (the source's name), the rate–quality plot if any, then one section
/// per file ([`section`]).
pub fn page(title: &str, plot: Option<&str>, sections: &[String]) -> String {
    let mut s = head(
        &format!("nmat report: {title}"),
        "img{image-rendering:pixelated;max-width:256px;min-width:64px;border:1px solid #888}\
         figure{display:inline-block;margin:4px}figcaption{font-size:80%}\
         section.file{border-top:2px solid #444;margin-top:2em}",
    );
    let _ = writeln!(
        s,
        "<p>Heat maps: the largest error of a map's channels at each texel, black 0 to white \
         {HEAT_FULL_SCALE} (unit scale) and above. Mips larger than {MAX_SIDE}² show their \
         top-left {MAX_SIDE}×{MAX_SIDE}.</p>"
    );
    if let Some(plot) = plot {
        s.push_str(plot);
    }
    for section in sections {
        s.push_str(section);
    }
    s.push_str("</body></html>\n");
    s
}

/// The part of the report about `m` (read from `path`, stored as `stored`) against its source
/// maps `set`, with the quality `q` measured on them and the decode of each mip it was measured
/// on (`decode_mip`'s values, as `metrics::chain_quality_keeping` hands them over).
pub fn section(
    path: &Path,
    m: &Material<'_>,
    stored: Stored,
    set: &TextureSet,
    q: &ChainQuality,
    decoded: &[Vec<f32>],
) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "<section class=\"file\">\n<h2 class=\"file\">{}</h2>",
        escape(&path.display().to_string())
    );
    let _ = writeln!(
        s,
        "<p class=\"summary\">{}×{}, {} mips, {} channels ({}); \
         <b>PSNR <span class=\"psnr\">{:.2}</span> dB</b> over all channels and mips, \
         SSIM <span class=\"ssim\">{:.4}</span> at mip 0, \
         <span class=\"bppc\">{:.4}</span> bits per pixel per channel on disk \
         ({:.4} in memory), {} bytes{}.</p>",
        m.width(),
        m.height(),
        m.mip_count(),
        m.channel_count(),
        codec_of(m),
        q.psnr,
        q.ssim,
        m.bppc_of(stored.len),
        m.bppc(),
        stored.len,
        if stored.packed { " packed" } else { "" }
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
            "<h3 class=\"map\">{name}</h3>\n<p>whole chain: PSNR <span class=\"map-psnr\">{:.2}</span> dB, \
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
                "<div class=\"mip\"><h4>mip {mip}: {}×{}{crop}</h4>",
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
    s.push_str("</section>\n");
    s
}

fn codec_of(m: &Material<'_>) -> String {
    match m.neural() {
        Some(n) => format!("neural, {} multiply-adds per texel", n.mlp().macs_per_texel()),
        None => "indexed JPEG".to_string(),
    }
}

/// The name the anchors' rows give a material: its folder's last component.
pub fn material_name(folder: &Path) -> String {
    let folder = std::path::absolute(folder).unwrap_or_else(|_| folder.to_path_buf());
    folder.file_name().map_or_else(|| folder.display().to_string(), |n| n.to_string_lossy().into())
}

/// One point of the rate–quality plot.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotPoint {
    /// The curve it is on: `nmat neural`, `nmat JPEG`, or another codec's name.
    pub series: String,
    /// What its tooltip and label say: a file name or a codec's setting.
    pub label: String,
    /// Bits per pixel per channel (on disk for a .nmat file).
    pub bppc: f64,
    /// PSNR over all channels and mips, dB.
    pub psnr: f64,
}

impl PlotPoint {
    /// The point of a .nmat file: its disk rate and its PSNR, labelled with its file name.
    pub fn of_file(path: &Path, m: &Material<'_>, q: &ChainQuality) -> Self {
        let series = if m.jpeg().is_some() { "nmat JPEG" } else { "nmat neural" };
        PlotPoint::labelled(series, path, q.bppc, q.psnr)
    }

    /// A point of `series` labelled with the name of the file at `path`.
    pub fn labelled(series: &str, path: &Path, bppc: f64, psnr: f64) -> Self {
        let label = path
            .file_name()
            .map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        PlotPoint { series: series.into(), label, bppc, psnr }
    }
}

/// The rows of an anchors CSV (`material,codec,setting,bppc,psnr_db[,…]`, as `nmat-anchors` and
/// `bench/quality.sh` write them; a header line, blank lines and `#` comments are skipped):
/// (material, point) each, the point's series the codec without its `@label`. An error names the
/// file and the line.
pub fn read_anchor_rows(path: &Path) -> Result<Vec<(String, PlotPoint)>, String> {
    let shown = path.display();
    let text = std::fs::read_to_string(path).map_err(|e| format!("--anchors {shown}: {e}"))?;
    let mut rows = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("material,") {
            continue;
        }
        let bad = |what: &str| format!("--anchors {shown} line {}: {what} in {line:?}", n + 1);
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() < 5 {
            return Err(bad("expected material,codec,setting,bppc,psnr_db"));
        }
        let number = |i: usize, name: &str| -> Result<f64, String> {
            match fields[i].parse::<f64>() {
                Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
                _ => Err(bad(&format!("{name} {:?} is not a positive number", fields[i]))),
            }
        };
        let codec = fields[1].split('@').next().unwrap_or(fields[1]);
        if fields[0].is_empty() || codec.is_empty() {
            return Err(bad("empty material or codec"));
        }
        let point = PlotPoint {
            series: codec.to_string(),
            label: format!("{} {}", fields[1], fields[2]),
            bppc: number(3, "bppc")?,
            psnr: number(4, "psnr_db")?,
        };
        rows.push((fields[0].to_string(), point));
    }
    Ok(rows)
}

/// The points of `material` among `rows` ([`read_anchor_rows`]).
pub fn anchors_of(rows: &[(String, PlotPoint)], material: &str) -> Vec<PlotPoint> {
    rows.iter().filter(|(m, _)| m == material).map(|(_, p)| p.clone()).collect()
}

/// [`read_anchor_rows`] of `material` only; an error when the file has none of its rows, saying
/// which materials it has.
pub fn read_anchors(path: &Path, material: &str) -> Result<Vec<PlotPoint>, String> {
    let rows = read_anchor_rows(path)?;
    let points = anchors_of(&rows, material);
    if points.is_empty() {
        let mut others: Vec<&str> = rows.iter().map(|(m, _)| m.as_str()).collect();
        others.sort_unstable();
        others.dedup();
        let has = if others.is_empty() { "no rows".to_string() } else { others.join(", ") };
        return Err(format!(
            "--anchors {}: no row for material {material:?} (it has: {has})",
            path.display()
        ));
    }
    Ok(points)
}

/// Plot size and margins, in SVG units.
const PLOT_W: f64 = 720.0;
const PLOT_H: f64 = 420.0;
const LEFT: f64 = 60.0;
const RIGHT: f64 = 170.0;
const TOP: f64 = 20.0;
const BOTTOM: f64 = 45.0;
/// Series colours, in order of first appearance (nmat's first).
const PALETTE: [&str; 8] =
    ["#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"];

/// An inline SVG rate–quality plot of `points`: BPPC on a logarithmic x axis, PSNR on y, one
/// colour per series, each series' points joined in order of rate, every point a `<circle
/// class="point">` carrying its numbers (`data-series`, `data-bppc`, `data-psnr`) and a tooltip.
pub fn plot(heading: &str, points: &[PlotPoint]) -> String {
    let mut series: Vec<&str> = Vec::new();
    for p in points {
        if !series.contains(&p.series.as_str()) {
            series.push(&p.series);
        }
    }
    series.sort_by_key(|s| !s.starts_with("nmat"));
    let (xs, ys): (Vec<f64>, Vec<f64>) = points.iter().map(|p| (p.bppc.log10(), p.psnr)).unzip();
    let (x0, x1) = padded(&xs, 0.08, 0.15);
    let (y0, y1) = padded(&ys, 0.08, 0.5);
    let (w, h) = (PLOT_W - LEFT - RIGHT, PLOT_H - TOP - BOTTOM);
    let sx = |bppc: f64| LEFT + (bppc.log10() - x0) / (x1 - x0) * w;
    let sy = |psnr: f64| TOP + (y1 - psnr) / (y1 - y0) * h;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "<h2>{}</h2>\n<svg class=\"rate-quality\" xmlns=\"http://www.w3.org/2000/svg\" \
         width=\"{PLOT_W}\" height=\"{PLOT_H}\" viewBox=\"0 0 {PLOT_W} {PLOT_H}\" \
         font-family=\"sans-serif\" font-size=\"12\">\n\
         <rect x=\"{LEFT}\" y=\"{TOP}\" width=\"{w}\" height=\"{h}\" fill=\"none\" stroke=\"#444\"/>",
        escape(heading)
    );
    for t in log_ticks(x0, x1) {
        let x = sx(t);
        let _ = writeln!(
            s,
            "<line x1=\"{x:.1}\" y1=\"{TOP}\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#ddd\"/>\
             <text x=\"{x:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            TOP + h,
            TOP + h + 15.0,
            trim_number(t)
        );
    }
    let step = linear_step(y1 - y0);
    let mut t = (y0 / step).ceil() * step;
    while t <= y1 {
        let y = sy(t);
        let _ = writeln!(
            s,
            "<line x1=\"{LEFT}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/>\
             <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
            LEFT + w,
            LEFT - 5.0,
            y + 4.0,
            trim_number(t)
        );
        t += step;
    }
    let _ = writeln!(
        s,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">bits per pixel per channel (log scale)</text>\
         <text transform=\"translate(15 {:.1}) rotate(-90)\" text-anchor=\"middle\">PSNR dB, all channels and mips</text>",
        LEFT + w / 2.0,
        PLOT_H - 8.0,
        TOP + h / 2.0
    );
    for (i, name) in series.iter().enumerate() {
        let colour = PALETTE[i % PALETTE.len()];
        let mut on: Vec<&PlotPoint> = points.iter().filter(|p| p.series == *name).collect();
        on.sort_by(|a, b| a.bppc.total_cmp(&b.bppc));
        if on.len() > 1 {
            let path: Vec<String> =
                on.iter().map(|p| format!("{:.1},{:.1}", sx(p.bppc), sy(p.psnr))).collect();
            let _ = writeln!(
                s,
                "<polyline points=\"{}\" fill=\"none\" stroke=\"{colour}\" stroke-width=\"1.5\"/>",
                path.join(" ")
            );
        }
        for p in &on {
            let (x, y) = (sx(p.bppc), sy(p.psnr));
            let _ = writeln!(
                s,
                "<circle class=\"point\" data-series=\"{}\" data-bppc=\"{:.4}\" data-psnr=\"{:.2}\" \
                 cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"4\" fill=\"{colour}\"><title>{}: {:.4} BPPC, {:.2} dB</title></circle>",
                escape(name),
                p.bppc,
                p.psnr,
                escape(&p.label),
                p.bppc,
                p.psnr
            );
            if name.starts_with("nmat") {
                let _ = writeln!(
                    s,
                    "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\">{}</text>",
                    x + 6.0,
                    y - 6.0,
                    escape(&p.label)
                );
            }
        }
        let ly = TOP + 10.0 + 18.0 * i as f64;
        let _ = writeln!(
            s,
            "<circle cx=\"{:.1}\" cy=\"{ly:.1}\" r=\"4\" fill=\"{colour}\"/>\
             <text class=\"legend\" x=\"{:.1}\" y=\"{:.1}\">{}</text>",
            LEFT + w + 15.0,
            LEFT + w + 25.0,
            ly + 4.0,
            escape(name)
        );
    }
    s.push_str("</svg>\n");
    s
}

/// The range of `v` widened by `share` of itself on each side, and to at least `least`.
fn padded(v: &[f64], share: f64, least: f64) -> (f64, f64) {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let pad = ((hi - lo) * share).max((least - (hi - lo)).max(0.0) / 2.0);
    (lo - pad, hi + pad)
}

/// Tick values 1, 2, 5 × 10^k between 10^lo and 10^hi (decimal logarithms).
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let mut out = Vec::new();
    for k in (lo.floor() as i32)..=(hi.ceil() as i32) {
        for m in [1.0, 2.0, 5.0] {
            let t = m * 10f64.powi(k);
            if (lo..=hi).contains(&t.log10()) {
                out.push(t);
            }
        }
    }
    out
}

/// A step of 1, 2 or 5 × 10^k giving at most 8 ticks over `span`.
fn linear_step(span: f64) -> f64 {
    let mut step = 10f64.powi((span / 8.0).log10().floor() as i32);
    for m in [1.0, 2.0, 5.0, 10.0] {
        if span / (m * step) <= 8.0 {
            step *= m;
            break;
        }
    }
    step
}

/// `v` without a float's noise (ticks are 1, 2, 5 × 10^k).
fn trim_number(v: f64) -> String {
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// One material of a library page ([`library_page`]).
pub struct LibraryRow {
    pub material: String,
    /// Its output and, when written, its report (`OUTPUT.html`), as links from the page.
    pub output: String,
    pub report: Option<String>,
    pub status: String,
    pub bppc: f64,
    pub psnr: f64,
    pub ssim: f64,
    pub seconds: f64,
}

/// `nmat build --report`'s page for the whole build: a table of every material (linking each
/// output's report) and a rate–quality plot for every source built more than once or with
/// anchor points (`plots`: heading, points).
pub fn library_page(
    title: &str,
    rows: &[LibraryRow],
    plots: &[(String, Vec<PlotPoint>)],
) -> String {
    let mut s = head(&format!("nmat build: {title}"), "td:nth-child(-n+2){text-align:left}");
    s.push_str(
        "<table id=\"materials\"><tr><th>material</th><th>output</th><th>status</th>\
         <th>BPPC</th><th>PSNR dB</th><th>SSIM</th><th>seconds</th></tr>\n",
    );
    for r in rows {
        let output = escape(&r.output);
        let report = r
            .report
            .as_ref()
            .map_or(String::new(), |href| format!(" (<a href=\"{}\">report</a>)", escape(href)));
        let numbers = if r.status == "failed" {
            "<td></td><td></td><td></td><td></td>".to_string()
        } else {
            format!(
                "<td>{:.4}</td><td>{:.2}</td><td>{:.4}</td><td>{:.1}</td>",
                r.bppc, r.psnr, r.ssim, r.seconds
            )
        };
        let _ = writeln!(
            s,
            "<tr class=\"material\"><td>{}</td><td>{output}{report}</td><td>{}</td>{numbers}</tr>",
            escape(&r.material),
            escape(&r.status)
        );
    }
    s.push_str("</table>\n");
    for (heading, points) in plots {
        s.push_str(&plot(heading, points));
    }
    s.push_str("</body></html>\n");
    s
}

/// `path` as a link from a page in `from`: relative when it lies under `from`, else a file URL;
/// characters a URL cannot carry percent-encoded.
pub fn link(path: &Path, from: &Path) -> String {
    let (path, from) = (
        std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()),
        std::path::absolute(from).unwrap_or_else(|_| from.to_path_buf()),
    );
    let (prefix, rest) = match path.strip_prefix(&from) {
        Ok(rest) => ("", rest.to_path_buf()),
        Err(_) => ("file://", path.clone()),
    };
    let mut out = prefix.to_string();
    for b in rest.to_string_lossy().bytes() {
        if b.is_ascii_alphanumeric() || b"/._-~".contains(&b) {
            out.push(b as char);
        } else {
            let _ = write!(out, "%{b:02X}");
        }
    }
    out
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
    fn axis_ticks_are_1_2_5_steps_inside_the_range() {
        let ticks = log_ticks(0.05f64.log10() - 1e-9, 2f64.log10() + 1e-9);
        let shown: Vec<String> = ticks.iter().map(|&t| trim_number(t)).collect();
        assert_eq!(shown, ["0.05", "0.1", "0.2", "0.5", "1", "2"]);
        // At most 8 steps, the smallest such: 12 dB in 2 dB steps, 3 dB in 0.5, 40 in 5.
        assert_eq!([12.0, 3.0, 40.0].map(linear_step), [2.0, 0.5, 5.0]);
    }

    #[test]
    fn links_are_relative_under_the_page_and_percent_encoded() {
        let page = Path::new("/lib/build");
        assert_eq!(link(Path::new("/lib/build/out/a b.html"), page), "out/a%20b.html");
        assert_eq!(link(Path::new("/else/x#1.html"), page), "file:///else/x%231.html");
    }

    #[test]
    fn anchor_rows_keep_codec_curves_and_name_a_bad_line() {
        let dir = std::env::temp_dir().join(format!("nmat-anchors-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.csv");
        std::fs::write(&path, "material,codec\n# note\n\nm,jpegxl@ntc-0.2,q60,0.2,33.5,1\n")
            .unwrap();
        let rows = read_anchor_rows(&path).unwrap();
        assert_eq!(rows.len(), 1);
        assert_eq!((rows[0].0.as_str(), rows[0].1.series.as_str()), ("m", "jpegxl"));
        assert_eq!((rows[0].1.bppc, rows[0].1.psnr), (0.2, 33.5));
        std::fs::write(&path, "m,avif,q,0.2\n").unwrap();
        assert!(read_anchor_rows(&path).unwrap_err().contains("line 1: expected"));
        std::fs::write(&path, "m,avif,q,0.2,-3\n").unwrap();
        assert!(read_anchor_rows(&path).unwrap_err().contains("psnr_db \"-3\""));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_heat_scale_runs_black_red_yellow_white() {
        assert_eq!(heat_colour(0.0), [0, 0, 0]);
        assert_eq!(heat_colour(1.0 / 3.0), [255, 0, 0]);
        assert_eq!(heat_colour(2.0 / 3.0), [255, 255, 0]);
        assert_eq!(heat_colour(5.0), [255, 255, 255]);
    }
}
