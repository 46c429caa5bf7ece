//! Per-texel decoding (docs/FORMAT.md §6): address the texel, gather the level's input features,
//! run the MLP in float or integer arithmetic, scale the outputs. Every function here is total for
//! a parsed material: any coordinate, mip and mask gives a value or a `BadArgument` error.

use crate::error::{Argument, Error};
use crate::format::channel::{AddressMode, Channel};
use crate::jpeg::Jpeg;
use crate::limits::{MAX_CHANNELS, MAX_FRAC_BITS, MAX_GRID_CHANNELS, MAX_GRIDS, MAX_WIDTH};
use crate::material::{Body, Material, Neural, TermMode};
#[cfg(feature = "alloc")]
use crate::neural::latents::Dequantizer;
use crate::neural::latents::{Footprint, LatentGrid, address, footprint};
use crate::neural::mlp::{forward_float, forward_int, saturate_i16};
use crate::neural::posenc::triangle_q;

/// Which output channels to decode: bit `c` selects channel `c`. Only the selected output rows of
/// the last layer are computed; outputs are written packed, in ascending channel order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ChannelMask(pub u16);

impl ChannelMask {
    /// Every channel the material has, whatever their number.
    pub const ALL: ChannelMask = ChannelMask(u16::MAX);

    /// The concrete mask for a material of `channel_count` channels: every bit names a real
    /// channel ([`ChannelMask::ALL`] becomes all of them), or `None` if the mask is empty or names
    /// a channel the material lacks. The one rule every engine (CPU, C API, GPU) applies.
    pub fn resolve(self, channel_count: usize) -> Option<u16> {
        let all = if channel_count >= 16 { u16::MAX } else { (1u16 << channel_count) - 1 };
        let mask = if self == ChannelMask::ALL { all } else { self.0 };
        (mask != 0 && mask & !all == 0).then_some(mask)
    }

    /// Channel `c` alone (`c` < 16).
    pub const fn single(c: u32) -> ChannelMask {
        ChannelMask(1u16.wrapping_shl(c))
    }
}

/// Raw features are kept in units of 2^-(16 + f): bilinear sums carry 16 extra fraction bits
/// (their weights sum to 2^16), every other feature is an exact multiple of 2^16.
pub(crate) const RAW_SHIFT: u32 = 16;

impl<'a> Material<'a> {
    /// The mask with every bit naming a real channel, or `BadArgument` (empty mask, or a bit at or
    /// beyond `channel_count` other than in [`ChannelMask::ALL`]).
    pub fn resolve_channels(&self, channels: ChannelMask) -> Result<u16, Error> {
        channels.resolve(self.channel_count()).ok_or(Error::BadArgument {
            argument: Argument::Channels,
            value: u64::from(channels.0),
            limit: ChannelMask::ALL.resolve(self.channel_count()).map_or(0, u64::from),
        })
    }

    /// How many values a decode with `channels` writes.
    pub fn required_len(&self, channels: ChannelMask) -> Result<usize, Error> {
        Ok(self.resolve_channels(channels)?.count_ones() as usize)
    }

    pub(crate) fn check_out(&self, channels: ChannelMask, out_len: usize) -> Result<u16, Error> {
        let mask = self.resolve_channels(channels)?;
        let needed = mask.count_ones() as usize;
        if out_len < needed {
            return Err(Error::BadArgument {
                argument: Argument::Output,
                value: out_len as u64,
                limit: needed as u64,
            });
        }
        Ok(mask)
    }

    /// The mip (clamped to the chain) and the texel (wrapped or clamped into that mip, §6.1).
    pub fn address_texel(&self, x: i64, y: i64, mip: u32) -> (u32, u32, u32) {
        let mip = mip.min(self.mip_count() - 1);
        let (w, h) = self.mip_size(mip);
        (address(x, w, self.address_mode), address(y, h, self.address_mode), mip)
    }

    /// The footprints of texel (x, y) of `mip` (already addressed) on every grid its level
    /// reads, and their cells' codes, into `reads` (emptied first): each grid once, however many
    /// terms use it. The first half of [`Material::gather`], apart so that the reads of all
    /// grids, and of several texels, are issued before any value is computed from them: a texel
    /// then waits for its cache misses once rather than once per grid.
    pub(crate) fn read_latents(
        &self,
        n: &Neural<'_>,
        (x, y, mip): (u32, u32, u32),
        reads: &mut TexelReads,
    ) {
        reads.clear();
        let mip_size = self.mip_size(mip);
        let Some(level) = n.levels.get(n.level_for_mip(mip)) else {
            return;
        };
        for term in &level.terms {
            // Nearest4 reads the first grid only; a bilinear term sums its whole chain.
            let grids = match term.mode {
                TermMode::Nearest4 => term.grids.get(..1).unwrap_or(&[]),
                TermMode::Bilinear => term.grids.as_slice(),
            };
            for &g in grids {
                let Some(grid) = n.grids.get(usize::from(g)) else { continue };
                if reads.iter().all(|r| r.grid != g) {
                    // A level holds at most MAX_GRIDS grids.
                    let _ = reads.push(Reads::new(g, grid, (x, y), mip_size, self.address_mode));
                }
            }
        }
    }

    /// Input features of texel (x, y) of `mip` (already addressed) in units of 2^-(16+f), passed
    /// to `sink` in input order, from its latents as [`Material::read_latents`] read them. The
    /// definition; `Decoder` spans have a faster twin (`decoder/span.rs`).
    pub(crate) fn gather<T: Feature>(
        &self,
        n: &Neural<'_>,
        (x, y, mip): (u32, u32, u32),
        reads: &TexelReads,
        sink: &mut Inputs<'_, T>,
    ) {
        let Some(level) = n.levels.get(n.level_for_mip(mip)) else {
            return;
        };
        let read = |g: u8| reads.iter().find(|r| r.grid == g);
        // The bilinear samples taken so far.
        let mut sampled = heapless::Vec::<(u8, [i32; MAX_GRID_CHANNELS]), MAX_GRIDS>::new();
        // The cells a `Nearest4` term dequantized, and their grid: a bilinear read of the same
        // grid (`ntc-0.2` reads its high-resolution grids both ways) weights them again.
        let (mut nearest, mut cells) = (None, [[0; MAX_GRID_CHANNELS]; 4]);
        for term in &level.terms {
            let channels = term
                .grids
                .first()
                .and_then(|&g| n.grids.get(usize::from(g)))
                .map_or(0, LatentGrid::channels);
            match term.mode {
                TermMode::Nearest4 => {
                    let Some(&g) = term.grids.first() else { continue };
                    let (Some(grid), Some(r)) = (n.grids.get(usize::from(g)), read(g)) else {
                        continue;
                    };
                    r.cells(grid, &mut cells);
                    for cell in &cells {
                        sink.push_latents(cell.get(..channels).unwrap_or(&[]));
                    }
                    nearest = Some(g);
                }
                TermMode::Bilinear => {
                    let mut sums = [0i64; MAX_GRID_CHANNELS];
                    for &g in &term.grids {
                        let (Some(grid), Some(r)) = (n.grids.get(usize::from(g)), read(g)) else {
                            continue;
                        };
                        // A grid in several chains (NBC's feature reuse) is sampled once.
                        let known = sampled.iter().find(|(index, _)| *index == g);
                        let values = match known {
                            Some((_, values)) => *values,
                            None => {
                                let values = if nearest == Some(g) {
                                    weighted(&cells, r, grid.channels())
                                } else {
                                    bilinear(grid, r)
                                };
                                let _ = sampled.push((g, values));
                                values
                            }
                        };
                        for (sum, &v) in sums.iter_mut().zip(&values).take(channels) {
                            *sum += i64::from(v);
                        }
                    }
                    for &sum in sums.iter().take(channels) {
                        sink.push(sum);
                    }
                }
            }
        }
        let f = n.mlp.input_frac_bits;
        for k in 0..n.mlp.pe_frequencies {
            for v in [
                triangle_q(x, k, 0, f),
                triangle_q(x, k, 1, f),
                triangle_q(y, k, 0, f),
                triangle_q(y, k, 1, f),
            ] {
                sink.push(i64::from(v) << RAW_SHIFT);
            }
        }
        if let Some(q) = n.mlp.lod_feature(mip) {
            sink.push(i64::from(q) << RAW_SHIFT);
        }
    }

    /// The input vector for texel (x, y) of `mip`: addressed, gathered and converted (for the
    /// integer network: rounded half up onto the input grid and saturated, §6.3). Entries past
    /// the input width are 0.
    pub(crate) fn inputs<T: Feature>(
        &self,
        n: &Neural<'_>,
        x: i64,
        y: i64,
        mip: u32,
    ) -> [T; MAX_WIDTH] {
        let texel = self.address_texel(x, y, mip);
        let mut reads = TexelReads::new();
        self.read_latents(n, texel, &mut reads);
        let mut io = [T::default(); MAX_WIDTH];
        self.gather_into(n, texel, &reads, &mut io);
        io
    }

    /// The network's input vector of an (addressed) texel into `io` (zeroed first), from its
    /// latents as [`Material::read_latents`] read them.
    #[inline(always)]
    fn gather_into<T: Feature>(
        &self,
        n: &Neural<'_>,
        texel: (u32, u32, u32),
        reads: &TexelReads,
        io: &mut [T; MAX_WIDTH],
    ) {
        *io = [T::default(); MAX_WIDTH];
        let input_frac_bits = n.mlp.input_frac_bits;
        self.gather(n, texel, reads, &mut Inputs { io, next: 0, input_frac_bits });
    }

    /// The float decode of an (unaddressed) texel for the rows in `rows`, in unit scale (1.0 =
    /// top of range): the network's outputs, or a JPEG texel's codes / 255 (FORMAT.md §11.5).
    pub(crate) fn run_float(&self, x: i64, y: i64, mip: u32, rows: u16) -> [f32; MAX_WIDTH] {
        match &self.body {
            Body::Neural(n) => {
                let mut io = self.inputs(n, x, y, mip);
                forward_float(&n.mlp.layers, &mut io, rows);
                io
            }
            Body::Jpeg(j) => {
                let mut io = [0f32; MAX_WIDTH];
                for (v, c) in io.iter_mut().zip(self.jpeg_codes(j, x, y, mip, rows)) {
                    *v = f32::from(c) / 255.0;
                }
                io
            }
        }
    }

    /// A JPEG material's 8-bit codes of an (unaddressed) texel, indexed by channel.
    pub(crate) fn jpeg_codes(
        &self,
        j: &Jpeg<'_>,
        x: i64,
        y: i64,
        mip: u32,
        rows: u16,
    ) -> [u8; MAX_CHANNELS] {
        let (x, y, mip) = self.address_texel(x, y, mip);
        j.texel_codes(x, y, mip, rows)
    }

    /// Float reference decode: values in each channel's range (§6.8), for the channels in
    /// `channels`, packed into `out`. Returns how many were written.
    pub fn decode_texel(
        &self,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        let rows = self.check_out(channels, out.len())?;
        let y_out = self.run_float(x, y, mip, rows);
        Ok(self.write_ranged(rows, &y_out, out))
    }

    /// Writes the selected float outputs mapped into their channels' ranges (§6.8).
    pub(crate) fn write_ranged(&self, rows: u16, y_out: &[f32], out: &mut [f32]) -> usize {
        let mut n = 0;
        for ((slot, v), ch) in
            out.iter_mut().zip(selected(y_out, rows)).zip(selected(&self.channels, rows))
        {
            *slot = ranged(ch, *v);
            n += 1;
        }
        n
    }

    /// Float reference decode in unit scale: each value is the network output clamped to [0, 1].
    pub fn decode_texel_unit(
        &self,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        let rows = self.check_out(channels, out.len())?;
        let y_out = self.run_float(x, y, mip, rows);
        Ok(write_selected(rows, &y_out, out, |v| unit(*v)))
    }

    /// Integer decode to 8-bit codes: `clamp((y·255 + 2^(f−1)) >> f, 0, 255)` (§6.7).
    pub fn decode_texel_u8(
        &self,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [u8],
    ) -> Result<usize, Error> {
        self.decode_codes(x, y, mip, channels, out, 255, |c| c as u8)
    }

    /// Integer decode to 16-bit codes: `clamp((y·65535 + 2^(f−1)) >> f, 0, 65535)` (§6.7).
    pub fn decode_texel_u16(
        &self,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [u16],
    ) -> Result<usize, Error> {
        self.decode_codes(x, y, mip, channels, out, 65535, |c| c as u16)
    }

    #[allow(clippy::too_many_arguments)] // the public signatures above, plus the code width
    fn decode_codes<T>(
        &self,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) -> Result<usize, Error> {
        let rows = self.check_out(channels, out.len())?;
        match &self.body {
            Body::Neural(n) => {
                let mut io = self.inputs(n, x, y, mip);
                forward_int(&n.mlp.layers, &mut io, rows);
                let f = n.last_frac_bits();
                Ok(write_selected(rows, &io, out, |&v| narrow(code(v, f, full_scale))))
            }
            Body::Jpeg(j) => {
                // 8-bit codes, widened exactly (c · 65535 / 255 = c · 257).
                let codes = self.jpeg_codes(j, x, y, mip, rows);
                Ok(write_selected(rows, &codes, out, |&c| narrow(i32::from(c) * full_scale / 255)))
            }
        }
    }
}

/// An input feature of the network: i16 on the input grid (integer decode) or f32 (float).
pub(crate) trait Feature: Copy + Default {
    /// The feature from a raw value in units of 2^-(16 + `input_frac_bits`).
    fn from_raw(raw: i64, input_frac_bits: u8) -> Self;
    /// [`Feature::from_raw`] of `high·2^16 + low`.
    #[cfg(feature = "alloc")]
    fn from_parts(high: i32, low: i32, input_frac_bits: u8) -> Self {
        Self::from_raw((i64::from(high) << RAW_SHIFT) + i64::from(low), input_frac_bits)
    }
    /// [`Feature::from_raw`] of one grid's bilinear sample (`value`: within [−2^31, 2^31 − 2^16],
    /// as [`bilinear`] states).
    #[cfg(feature = "alloc")]
    fn from_bilinear(value: i32, input_frac_bits: u8) -> Self {
        Self::from_raw(i64::from(value), input_frac_bits)
    }
    /// [`Feature::from_raw`] of a dequantized latent (an i16 on the input grid, FORMAT.md §4).
    fn from_latent(value: i32, input_frac_bits: u8) -> Self {
        Self::from_raw(i64::from(value) << RAW_SHIFT, input_frac_bits)
    }
}

impl Feature for i16 {
    /// §6.3: rounded half up onto the input grid, saturated.
    fn from_raw(raw: i64, _: u8) -> i16 {
        saturate_i16((raw + (1 << (RAW_SHIFT - 1))) >> RAW_SHIFT)
    }

    /// In i32: `(high·2^16 + low + 2^15) >> 16 = high + ((low + 2^15) >> 16)`, for `high` and
    /// `low` far enough from the i32 limits (as the span gather's are: |high| ≤ 8·2^15,
    /// 0 ≤ low < 8·2^16).
    #[cfg(feature = "alloc")]
    fn from_parts(high: i32, low: i32, _: u8) -> i16 {
        let v = high + ((low + (1 << (RAW_SHIFT - 1))) >> RAW_SHIFT);
        v.clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16
    }

    /// In i32: `value + 2^15` stays below 2^31 for a value at most 2^31 − 2^16; the shifted
    /// value is within the i16 range already.
    #[cfg(feature = "alloc")]
    fn from_bilinear(value: i32, _: u8) -> i16 {
        (value.wrapping_add(1 << (RAW_SHIFT - 1)) >> RAW_SHIFT) as i16
    }

    /// A latent is already on the input grid: rounding and saturation leave it unchanged.
    fn from_latent(value: i32, _: u8) -> i16 {
        value as i16
    }
}

impl Feature for f32 {
    /// Saturated to the i16 range of the input grid and scaled to real units (the nearest f32;
    /// the scale is a power of two).
    fn from_raw(raw: i64, input_frac_bits: u8) -> f32 {
        let (lo, hi) = (i64::from(i16::MIN) << RAW_SHIFT, i64::from(i16::MAX) << RAW_SHIFT);
        // 2^-(16 + f) built from its exponent (f ≤ 14: a normal f32), without a division.
        let exponent = 127 - RAW_SHIFT - u32::from(input_frac_bits.min(MAX_FRAC_BITS));
        raw.clamp(lo, hi) as f32 * f32::from_bits(exponent << 23)
    }
}

/// Where `gather` puts the input features: an input vector filled in order from its first
/// entry (entries past the features pushed are left alone).
pub(crate) struct Inputs<'o, T> {
    io: &'o mut [T; MAX_WIDTH],
    next: usize,
    input_frac_bits: u8,
}

impl<T: Feature> Inputs<'_, T> {
    fn push(&mut self, raw: i64) {
        if let Some(v) = self.io.get_mut(self.next) {
            *v = T::from_raw(raw, self.input_frac_bits);
        }
        self.next += 1;
    }

    /// Dequantized latents (each an i16 on the input grid, FORMAT.md §4), in one pass.
    fn push_latents(&mut self, values: &[i32]) {
        let end = (self.next + values.len()).min(MAX_WIDTH);
        if let Some(slots) = self.io.get_mut(self.next..end) {
            for (slot, &v) in slots.iter_mut().zip(values) {
                *slot = T::from_latent(v, self.input_frac_bits);
            }
        }
        self.next += values.len();
    }
}

/// The bilinear sample of a texel on `grid`, from its footprint as read in `r`, per channel, in
/// units of 2^-(16+f): the footprint's 4 cells weighted by products of 1/256 fractions (§6.2).
/// Exact: weights in 1/65536 summing to 65536 and values i16 keep each sum in
/// [−2^31, 2^31 − 2^16].
#[inline(always)]
fn bilinear(grid: &LatentGrid<'_>, r: &Reads) -> [i32; MAX_GRID_CHANNELS] {
    let mut cells = [[0; MAX_GRID_CHANNELS]; 4];
    r.cells(grid, &mut cells);
    weighted(&cells, r, grid.channels())
}

/// [`bilinear`] of a footprint whose 4 cells are dequantized already (in the order of
/// [`Reads::cells`]), over its first `channels` channels (the others 0).
#[inline(always)]
pub(crate) fn weighted(
    cells: &[[i32; MAX_GRID_CHANNELS]; 4],
    r: &Reads,
    channels: usize,
) -> [i32; MAX_GRID_CHANNELS] {
    let [c00, c10, c01, c11] = cells;
    let (fx, fy) = (r.footprint.fx, r.footprint.fy);
    let (gx, gy) = (256 - fx, 256 - fy);
    let w = [gx * gy, fx * gy, gx * fy, fx * fy];
    let mut values = [0i32; MAX_GRID_CHANNELS];
    // Lanes past the grid's channels stay 0.
    let lanes = values.iter_mut().zip(c00).zip(c10).zip(c01).zip(c11);
    for ((((v, &a), &b), &c), &d) in lanes.take(channels) {
        *v = (w[0].wrapping_mul(a))
            .wrapping_add(w[1].wrapping_mul(b))
            .wrapping_add(w[2].wrapping_mul(c))
            .wrapping_add(w[3].wrapping_mul(d));
    }
    values
}

/// What [`Material::read_latents`] reads for one texel: a [`Reads`] per grid of its level.
pub(crate) type TexelReads = heapless::Vec<Reads, MAX_GRIDS>;

/// The footprint of a texel on one grid and its cells' codes as read, a [`Row`] per row (y0, y1).
pub(crate) struct Reads {
    grid: u8,
    footprint: Footprint,
    rows: [Row; 2],
}

/// The codes of a footprint row's two cells, as [`LatentGrid::cells_window`] reads them: both
/// in one window where one holds them, else a window per cell (`None`: a cell it cannot read,
/// left to [`LatentGrid::cell_values`]).
#[derive(Clone, Copy)]
enum Row {
    Pair(u64),
    Cells(Option<u64>, Option<u64>),
}

impl Row {
    /// Cells (x0, y) and (x1, y) of footprint `fp` on `grid`.
    #[inline(always)]
    fn read(grid: &LatentGrid<'_>, fp: &Footprint, y: u32) -> Row {
        let pair =
            if fp.x1 == fp.x0.wrapping_add(1) { grid.cells_window(fp.x0, y, 2) } else { None };
        match pair {
            Some(codes) => Row::Pair(codes),
            None => Row::Cells(grid.cells_window(fp.x0, y, 1), grid.cells_window(fp.x1, y, 1)),
        }
    }
}

impl Reads {
    /// Texel (x, y) (addressed) of a `mip_size` mip on grid number `index`, `grid`.
    #[inline(always)]
    pub(crate) fn new(
        index: u8,
        grid: &LatentGrid<'_>,
        (x, y): (u32, u32),
        mip_size: (u32, u32),
        mode: AddressMode,
    ) -> Reads {
        let fp = footprint((grid.width(), grid.height()), x, y, mip_size, mode);
        Reads {
            grid: index,
            footprint: fp,
            rows: [Row::read(grid, &fp, fp.y0), Row::read(grid, &fp, fp.y1)],
        }
    }

    /// [`Reads::cells`] with the grid's dequantization prepared: the same values in the grid's
    /// channels, 0 in the lanes past them.
    #[cfg(feature = "alloc")]
    #[inline(always)]
    pub(crate) fn cells_prepared(
        &self,
        grid: &LatentGrid<'_>,
        dequantizer: &Dequantizer,
        cells: &mut [[i32; MAX_GRID_CHANNELS]; 4],
    ) {
        let fp = &self.footprint;
        let [c00, c10, c01, c11] = cells;
        for ((left, right), (y, row)) in
            [(c00, c10), (c01, c11)].into_iter().zip([fp.y0, fp.y1].into_iter().zip(self.rows))
        {
            match row {
                Row::Pair(codes) => dequantizer.pair(codes, (left, right)),
                Row::Cells(l, r) => {
                    for (x, window, out) in [(fp.x0, l, left), (fp.x1, r, right)] {
                        match window {
                            Some(codes) => dequantizer.cell(codes, 0, out),
                            None => grid.cell_values(x, y, out),
                        }
                    }
                }
            }
        }
    }

    /// The dequantized values of the 4 cells into `cells`, in the order (x0, y0), (x1, y0),
    /// (x0, y1), (x1, y1); channels past the grid's are left alone.
    #[inline(always)]
    fn cells(&self, grid: &LatentGrid<'_>, cells: &mut [[i32; MAX_GRID_CHANNELS]; 4]) {
        let fp = &self.footprint;
        let [c00, c10, c01, c11] = cells;
        for ((left, right), (y, row)) in
            [(c00, c10), (c01, c11)].into_iter().zip([fp.y0, fp.y1].into_iter().zip(self.rows))
        {
            match row {
                Row::Pair(codes) => grid.dequantize_pair(codes, (left, right)),
                Row::Cells(l, r) => {
                    for (x, window, out) in [(fp.x0, l, left), (fp.x1, r, right)] {
                        match window {
                            Some(codes) => {
                                grid.dequantize(codes, out);
                            }
                            None => grid.cell_values(x, y, out),
                        }
                    }
                }
            }
        }
    }
}

/// Unit-scale clamp; NaN (impossible for validated weights, but cheap to rule out) maps to 0.
pub(crate) fn unit(v: f32) -> f32 {
    if v >= 1.0 {
        1.0
    } else if v > 0.0 {
        v
    } else {
        0.0
    }
}

/// A unit-scale value (clamped to [0, 1]) mapped into `ch`'s range (§6.8).
pub(crate) fn ranged(ch: &Channel<'_>, v: f32) -> f32 {
    let u = unit(v);
    ch.range_min * (1.0 - u) + ch.range_max * u
}

/// The integer network's input vector of texel (x, y) of `mip` (addressed as every decoder
/// addresses it; entries past the input width 0), or `None` for a JPEG material: what a trainer
/// that refits a layer on the decoder's exact activations starts from (`internals`).
pub fn input_vector(m: &Material<'_>, x: i64, y: i64, mip: u32) -> Option<[i16; MAX_WIDTH]> {
    match m.body() {
        Body::Neural(n) => Some(m.inputs(n, x, y, mip)),
        Body::Jpeg(_) => None,
    }
}

/// Output code of a Q.`f` value for a full scale of `max` (255 or 65535). |y·max| < 2^31.
#[inline(always)]
pub fn code(y: i16, f: u32, max: i32) -> i32 {
    let half = 1i32 << (f.clamp(1, 14) - 1);
    ((i32::from(y) * max + half) >> f.clamp(1, 14)).clamp(0, max)
}

pub(crate) fn selected<T>(items: &[T], rows: u16) -> impl Iterator<Item = &T> {
    // The set bits of `rows`, lowest first: one step per selected item, not one per item.
    let mut bits = rows;
    core::iter::from_fn(move || {
        if bits == 0 {
            return None;
        }
        let i = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        Some(i)
    })
    .filter_map(move |i| items.get(i))
}

pub(crate) fn write_selected<S, T>(
    rows: u16,
    values: &[S],
    out: &mut [T],
    map: impl Fn(&S) -> T,
) -> usize {
    let mut n = 0;
    for (slot, v) in out.iter_mut().zip(selected(values, rows)) {
        *slot = map(v);
        n += 1;
    }
    n
}

#[cfg(all(test, feature = "alloc"))]
mod tests {
    use super::*;

    /// The i32 shortcut for one grid's bilinear sample equals the definition's rounding at the
    /// ends of the sample's range (4 cells of ±32767 or −32768 weighted to 2^16) and between.
    #[test]
    fn from_bilinear_equals_from_raw_over_a_sample_s_range() {
        let (lo, hi) = (i32::MIN, i32::MAX - (1 << 16) + 1);
        let ends = [lo, lo + 1, -(1 << 15) - 1, -(1 << 15), -1, 0, 1, 1 << 15, hi - 1, hi];
        let between =
            (0..10_000i64).map(|k| (i64::from(lo) + k * 429_490_000 % (1i64 << 32)) as i32);
        for v in ends.into_iter().chain(between.filter(|&v| v <= hi)) {
            assert_eq!(i16::from_bilinear(v, 12), i16::from_raw(i64::from(v), 12), "{v}");
            let (a, b) = (f32::from_bilinear(v, 12), f32::from_raw(i64::from(v), 12));
            assert_eq!(a.to_bits(), b.to_bits(), "{v}");
        }
    }

    /// The unit clamp gives values in [0, 1] as bits a caller can compare: +0 for every value
    /// at or below 0, −0 and NaN included; 1 from 1 up; the value itself between.
    #[test]
    fn the_unit_clamp_gives_positive_zero_below_and_one_above() {
        for v in [-0.0f32, 0.0, -1.0, f32::NAN, f32::NEG_INFINITY, -f32::MIN_POSITIVE] {
            assert_eq!(unit(v).to_bits(), 0.0f32.to_bits(), "{v}");
        }
        for v in [1.0f32, 1.5, f32::INFINITY] {
            assert_eq!(unit(v).to_bits(), 1.0f32.to_bits(), "{v}");
        }
        for v in [f32::MIN_POSITIVE, 0.25, 1.0 - f32::EPSILON / 2.0] {
            assert_eq!(unit(v).to_bits(), v.to_bits(), "{v}");
        }
    }
}
