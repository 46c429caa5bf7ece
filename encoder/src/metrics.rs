//! Quality as the literature measures it: PSNR over all channels and the whole mip chain (the NTC
//! paper's figure), per map and per mip, SSIM at mip 0, and bits per pixel per channel.

use crate::texset::TextureSet;
use nmat_core::{ChannelMask, Decoder, Material};
use rayon::prelude::*;

/// Integer-decoded unit values of one mip, `w × h × channels`, channel fastest.
pub fn decode_mip(m: &Material<'_>, mip: u32) -> Vec<f32> {
    decode_mip_with(m, mip, &mut |_| {})
}

/// Rows decoded between two progress reports of [`decode_mip_with`].
const PROGRESS_ROWS: usize = 32;

/// [`decode_mip`], telling `progress` how many texels were decoded after every band of rows
/// (on the calling thread; the rows of a band are decoded in parallel).
pub fn decode_mip_with(m: &Material<'_>, mip: u32, progress: &mut dyn FnMut(u64)) -> Vec<f32> {
    let (w, h) = m.mip_size(mip);
    let row_len = w as usize * m.channel_count();
    let decoder = Decoder::new(m);
    let mut out = vec![0f32; row_len * h as usize];
    // Rows in parallel; a JPEG material's in tiles of whole MCU rows (each MCU decoded once).
    let tile = if m.jpeg().is_some() { 16 } else { 1 };
    for (band, rows) in out.chunks_mut(row_len * PROGRESS_ROWS).enumerate() {
        rows.par_chunks_mut(row_len * tile).enumerate().for_each(|(i, tile_rows)| {
            let y = (band * PROGRESS_ROWS + i * tile) as u32;
            let height = (tile_rows.len() / row_len.max(1)) as u32;
            let mut codes = vec![0u8; tile_rows.len()];
            // A valid material, region, mask and buffer: this cannot fail.
            let _ = decoder.decode_region_u8(
                m,
                mip,
                (0, y, w, height),
                ChannelMask::ALL,
                &mut codes,
                0,
            );
            for (v, &code) in tile_rows.iter_mut().zip(&codes) {
                *v = f32::from(code) / 255.0;
            }
        });
        progress((rows.len() / row_len.max(1)) as u64 * u64::from(w));
    }
    out
}

/// The decoded value a channel stands for, in unit scale of its source map (constants included).
pub fn unit_of(m: &Material<'_>, channel: usize, decoded_unit: f32) -> f32 {
    let ch = &m.channels()[channel];
    if ch.range_min == ch.range_max {
        // A constant channel: its value is the range; back to the map's unit scale.
        let (lo, hi) = ch.nominal_range();
        (ch.range_min - lo) / (hi - lo)
    } else {
        decoded_unit
    }
}

pub fn psnr(mse: f64) -> f64 {
    if mse <= 0.0 { f64::INFINITY } else { -10.0 * mse.log10() }
}

#[derive(Clone, Debug, Default)]
pub struct ChainQuality {
    /// PSNR over all channels of all mips (squared errors summed over every sample).
    pub psnr: f64,
    /// `[mip][channel]` mean squared error.
    pub mse: Vec<Vec<f64>>,
    /// Mean SSIM over channels at mip 0.
    pub ssim: f64,
    /// Bits per pixel per channel of the file as stored (packed or not), over the channels that
    /// carry information.
    pub bppc: f64,
    /// The same of the fixed-rate form decoders hold in memory.
    pub memory_bppc: f64,
    /// Per channel, the mean of decode minus source over the chain (every sample of every mip,
    /// unit scale): a network's constant offset, which `nmat_encode` calibrates away.
    pub mean_error: Vec<f64>,
}

impl ChainQuality {
    /// PSNR of channels `channels` at `mip`, or over the chain if `mip` is `None`.
    pub fn psnr_of(&self, channels: &[usize], mip: Option<usize>, set: &TextureSet) -> f64 {
        let (mut sum, mut n) = (0.0, 0.0);
        for (m, row) in self.mse.iter().enumerate() {
            if mip.is_some_and(|k| k != m) {
                continue;
            }
            let texels = f64::from(set.mips[m].width * set.mips[m].height);
            for &c in channels {
                sum += row[c] * texels;
                n += texels;
            }
        }
        psnr(sum / n.max(1.0))
    }
}

/// Compares the integer decode of `m` with the source chain of `set`.
pub fn chain_quality(m: &Material<'_>, set: &TextureSet) -> ChainQuality {
    chain_quality_with(m, set, &mut |_| {})
}

/// [`chain_quality`], telling `progress` how many texels were decoded as the decode goes (all
/// mips together are [`Material::decode_cost`]'s texels summed over the chain).
pub fn chain_quality_with(
    m: &Material<'_>,
    set: &TextureSet,
    progress: &mut dyn FnMut(u64),
) -> ChainQuality {
    chain_quality_keeping(m, set, progress, &mut |_, _| {})
}

/// [`chain_quality_with`], handing each mip's decode ([`decode_mip`]'s values, mip by mip) to
/// `keep` once it is measured, for a caller that shows them (`nmat eval --report`) without
/// decoding the chain again.
pub fn chain_quality_keeping(
    m: &Material<'_>,
    set: &TextureSet,
    progress: &mut dyn FnMut(u64),
    keep: &mut dyn FnMut(usize, Vec<f32>),
) -> ChainQuality {
    let c = set.channel_count();
    let (mut total, mut count) = (0.0f64, 0.0f64);
    let mut mse = Vec::new();
    let mut ssim = 0.0;
    let mut error_sum = vec![0.0f64; c];
    for (mip, src) in set.mips.iter().enumerate() {
        let decoded = decode_mip_with(m, mip as u32, progress);
        let mut per = vec![0.0f64; c];
        for (i, (&d, &s)) in decoded.iter().zip(&src.data).enumerate() {
            let ch = i % c;
            let e = f64::from(unit_of(m, ch, d) - s);
            per[ch] += e * e;
            error_sum[ch] += e;
        }
        let n = f64::from(src.width * src.height);
        total += per.iter().sum::<f64>();
        count += n * c as f64;
        mse.push(per.into_iter().map(|s| s / n).collect());
        if mip == 0 {
            let decoded: Vec<f32> =
                decoded.iter().enumerate().map(|(i, &d)| unit_of(m, i % c, d)).collect();
            ssim = (0..c)
                .map(|ch| ssim_channel(&src.data, &decoded, src.width, src.height, c, ch))
                .sum::<f64>()
                / c as f64;
        }
        keep(mip, decoded);
    }
    let samples = count / c.max(1) as f64;
    let mean_error = error_sum.into_iter().map(|e| e / samples.max(1.0)).collect();
    let (bppc, memory_bppc) = (m.bppc(), m.bppc());
    ChainQuality { psnr: psnr(total / count), mse, ssim, bppc, memory_bppc, mean_error }
}

/// SSIM (Wang et al. 2004) of one channel: 11×11 Gaussian window (σ = 1.5), K1 = 0.01,
/// K2 = 0.03, dynamic range 1, mean over the valid window positions (whole image if smaller).
pub fn ssim_channel(a: &[f32], b: &[f32], w: u32, h: u32, stride: usize, ch: usize) -> f64 {
    const R: i64 = 5;
    let g: Vec<f64> = (-R..=R).map(|i| (-(i * i) as f64 / (2.0 * 1.5 * 1.5)).exp()).collect();
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let (w, h) = (i64::from(w), i64::from(h));
    let at = |img: &[f32], x: i64, y: i64| {
        let (x, y) = (x.clamp(0, w - 1), y.clamp(0, h - 1));
        f64::from(img[(y * w + x) as usize * stride + ch])
    };
    let (x0, x1) = if w > 2 * R { (R, w - R) } else { (0, w) };
    let (y0, y1) = if h > 2 * R { (R, h - R) } else { (0, h) };
    let rows: Vec<(f64, f64)> = (y0..y1)
        .into_par_iter()
        .map(|y| {
            let mut sum = 0.0;
            for x in x0..x1 {
                let (mut wsum, mut ma, mut mb, mut aa, mut bb, mut ab) =
                    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
                for dy in -R..=R {
                    for dx in -R..=R {
                        let k = g[(dy + R) as usize] * g[(dx + R) as usize];
                        let (va, vb) = (at(a, x + dx, y + dy), at(b, x + dx, y + dy));
                        wsum += k;
                        ma += k * va;
                        mb += k * vb;
                        aa += k * va * va;
                        bb += k * vb * vb;
                        ab += k * va * vb;
                    }
                }
                let (ma, mb) = (ma / wsum, mb / wsum);
                let va = aa / wsum - ma * ma;
                let vb = bb / wsum - mb * mb;
                let cov = ab / wsum - ma * mb;
                sum += ((2.0 * ma * mb + c1) * (2.0 * cov + c2))
                    / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            }
            (sum, (x1 - x0) as f64)
        })
        .collect();
    let (s, n) = rows.iter().fold((0.0, 0.0), |acc, r| (acc.0 + r.0, acc.1 + r.1));
    s / n.max(1.0)
}
