//! Texture filtering on top of per-texel decoding (docs/FORMAT.md §6.9): nearest (1 decode),
//! bilinear (4), trilinear (8) and stochastic (1: the NTC paper's filtering by random selection,
//! with the caller's random numbers — the core keeps no RNG state).

use crate::decode::ChannelMask;
use crate::error::Error;
use crate::limits::MAX_CHANNELS;
use crate::material::Material;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    /// The texel under (u, v) at the nearest mip.
    Nearest,
    /// Bilinear between the 4 nearest texels of the nearest mip.
    Bilinear,
    /// Bilinear on the two mips around `lod`, blended.
    Trilinear,
    /// One texel drawn from the trilinear footprint with probability equal to its weight: unbiased
    /// on average, one decode per sample.
    Stochastic,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    /// The float reference decoder.
    Float,
    /// The integer decoder (8-bit codes), bit-identical across engines.
    Integer,
}

/// One filtered lookup.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleRequest {
    /// Normalized coordinates: (0, 0) is the top-left corner of texel (0, 0), (1, 1) the
    /// bottom-right corner of the last texel. Outside [0, 1] the address mode applies; NaN is 0.
    pub u: f32,
    pub v: f32,
    /// Mip level, fractional. Clamped to [0, mip_count − 1]; NaN is 0.
    pub lod: f32,
    pub filter: Filter,
    pub precision: Precision,
    /// Uniform numbers in [0, 1) for `Stochastic` (x, y, mip choice); ignored otherwise.
    /// Values outside are clamped; NaN is 0.
    pub random: [f32; 3],
    pub channels: ChannelMask,
}

/// A texel decoder in unit scale: (x, y, mip, channels, precision, out) → values written.
pub(crate) type TexelUnit<'f> =
    dyn Fn(i64, i64, u32, ChannelMask, Precision, &mut [f32]) -> Result<usize, Error> + 'f;

fn finite_or_zero(v: f32) -> f64 {
    if v.is_nan() { 0.0 } else { f64::from(v) }
}

/// Texel-space footprint along one axis: first texel and the weight of the second.
fn axis(u: f32, size: u32, centred: bool) -> (i64, f64) {
    let p = finite_or_zero(u) * f64::from(size) - if centred { 0.5 } else { 0.0 };
    let p = p.clamp(-9.0e15, 9.0e15); // keeps the fraction meaningful and the i64 cast exact
    let base = libm::floor(p);
    (base as i64, p - base)
}

impl<'a> Material<'a> {
    /// Filtered sample: values in each channel's range, packed for the channels selected.
    pub fn sample(&self, req: &SampleRequest, out: &mut [f32]) -> Result<usize, Error> {
        self.sample_with(req, out, &|x, y, mip, channels, precision, out| {
            self.texel_unit(x, y, mip, channels, precision, out)
        })
    }

    /// [`Material::sample`] with texels in unit scale from `texel` (x, y, mip, channels,
    /// precision, out), which must decode like [`Material::decode_texel_unit`] (float) or
    /// `decode_texel_u8 / 255` (integer).
    pub(crate) fn sample_with(
        &self,
        req: &SampleRequest,
        out: &mut [f32],
        texel: &TexelUnit<'_>,
    ) -> Result<usize, Error> {
        let rows = self.resolve_channels(req.channels)?;
        let n = rows.count_ones() as usize;
        if out.len() < n {
            return Err(Error::BadArgument {
                argument: crate::error::Argument::Output,
                value: out.len() as u64,
                limit: n as u64,
            });
        }
        let last = f64::from(self.mip_count() - 1);
        let lod = finite_or_zero(req.lod).clamp(0.0, last);
        let nearest_mip = libm::floor(lod + 0.5) as u32;
        let low_mip = libm::floor(lod) as u32;
        let high_mip = (low_mip + 1).min(self.mip_count() - 1);
        let t = lod - f64::from(low_mip);
        let r = req.random.map(|v| finite_or_zero(v).clamp(0.0, 1.0));
        let mut acc = [0f64; MAX_CHANNELS];
        let mut add = |x: i64, y: i64, mip: u32, w: f64| -> Result<(), Error> {
            if w == 0.0 {
                return Ok(());
            }
            let mut vals = [0f32; MAX_CHANNELS];
            texel(x, y, mip, ChannelMask(rows), req.precision, &mut vals)?;
            for (a, v) in acc.iter_mut().zip(vals).take(n) {
                *a += w * f64::from(v);
            }
            Ok(())
        };
        match req.filter {
            Filter::Nearest => {
                let (w, h) = self.mip_size(nearest_mip);
                add(axis(req.u, w, false).0, axis(req.v, h, false).0, nearest_mip, 1.0)?;
            }
            Filter::Bilinear => self.bilinear(req, nearest_mip, 1.0, &mut add)?,
            Filter::Trilinear => {
                self.bilinear(req, low_mip, 1.0 - t, &mut add)?;
                if high_mip != low_mip {
                    self.bilinear(req, high_mip, t, &mut add)?;
                }
            }
            Filter::Stochastic => {
                let mip = if r[2] < t { high_mip } else { low_mip };
                let (w, h) = self.mip_size(mip);
                let (x0, fx) = axis(req.u, w, true);
                let (y0, fy) = axis(req.v, h, true);
                let x = if r[0] < fx { x0.saturating_add(1) } else { x0 };
                let y = if r[1] < fy { y0.saturating_add(1) } else { y0 };
                add(x, y, mip, 1.0)?;
            }
        }
        let mut selected = self.channels.iter().enumerate().filter(|(i, _)| rows & (1 << i) != 0);
        for (slot, a) in out.iter_mut().zip(acc).take(n) {
            if let Some((_, ch)) = selected.next() {
                let unit = a.clamp(0.0, 1.0) as f32;
                *slot = ch.range_min * (1.0 - unit) + ch.range_max * unit;
            }
        }
        Ok(n)
    }

    fn bilinear(
        &self,
        req: &SampleRequest,
        mip: u32,
        weight: f64,
        add: &mut impl FnMut(i64, i64, u32, f64) -> Result<(), Error>,
    ) -> Result<(), Error> {
        let (w, h) = self.mip_size(mip);
        let (x0, fx) = axis(req.u, w, true);
        let (y0, fy) = axis(req.v, h, true);
        let (x1, y1) = (x0.saturating_add(1), y0.saturating_add(1));
        add(x0, y0, mip, weight * (1.0 - fx) * (1.0 - fy))?;
        add(x1, y0, mip, weight * fx * (1.0 - fy))?;
        add(x0, y1, mip, weight * (1.0 - fx) * fy)?;
        add(x1, y1, mip, weight * fx * fy)
    }

    /// One texel in unit scale by the requested decoder.
    fn texel_unit(
        &self,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        precision: Precision,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        match precision {
            Precision::Float => self.decode_texel_unit(x, y, mip, channels, out),
            Precision::Integer => {
                let mut codes = [0u8; MAX_CHANNELS];
                let n = self.decode_texel_u8(x, y, mip, channels, &mut codes)?;
                for (o, c) in out.iter_mut().zip(codes).take(n) {
                    *o = f32::from(c) / 255.0;
                }
                Ok(n)
            }
        }
    }
}
