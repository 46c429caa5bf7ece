//! The input vectors of consecutive texels of one row (the gather of [`Decoder`] spans): the same
//! features, in the same order and to the bit, as `Material::gather` (FORMAT.md §6.2–§6.5), with
//! everything that does not change from texel to texel computed only when it changes.
//!
//! The span keeps an input vector (the template) between texels. Once per span: the addressed
//! row, each grid's two cell rows and vertical fraction, and the features of y (positional
//! encoding, LOD) written into the template. Per texel: each grid's x axis (stepped, not
//! divided); a new column of cells (two cells) decoded only when the texel crosses into it, and
//! a nearest term's features rewritten only then; the bilinear features and the positional
//! encoding of x; then the template is copied out. A bilinear column is kept blended vertically
//! (`gy·top + fy·bottom`), so a texel costs two multiply-adds per channel: `gx·left + fx·right`
//! is the definition's `Σ w·cell` exactly (the same integer, in the i32 range the definition
//! states).
//!
//! [`Decoder`]: super::Decoder

use crate::decode::{Feature, RAW_SHIFT};
use crate::latents::{AxisStepper, LatentGrid, address, axis};
use crate::limits::{MAX_CHAIN, MAX_GRID_CHANNELS, MAX_TERMS, MAX_WIDTH};
use crate::material::{AddressMode, Material, TermMode};
use crate::posenc::triangle_q;

type Column = [i32; MAX_GRID_CHANNELS];

/// One grid of one term, for the row of the span.
#[derive(Clone, Copy)]
struct Slot<'a> {
    grid: LatentGrid<'a>,
    bilinear: bool,
    /// The two cell rows (addressed) and the vertical fraction in 1/256.
    rows: (u32, u32),
    fy: i32,
    x_axis: AxisStepper,
    /// The first cell index (before addressing) of the columns held, if any.
    held: Option<i64>,
    /// Left and right columns: (top, bottom) cells, or for a bilinear grid the blended column in
    /// `.0` (`.1` unused).
    columns: [(Column, Column); 2],
}

impl Slot<'_> {
    /// Steps to texel `x` of a `mip_width` row: the horizontal fraction in 1/256, and whether
    /// the columns changed.
    fn advance(&mut self, x: u32, mip_width: u32, mode: AddressMode) -> (i32, bool) {
        let width = self.grid.width().max(1);
        let (i, fx) = self.x_axis.at(x, mip_width, width);
        if self.held == Some(i) {
            return (fx, false);
        }
        if self.held == Some(i - 1) {
            let [left, right] = &mut self.columns;
            *left = *right;
        } else {
            self.load(0, address(i, width, mode));
        }
        self.load(1, address(i + 1, width, mode));
        self.held = Some(i);
        (fx, true)
    }

    fn load(&mut self, side: usize, column: u32) {
        let (fy, bilinear) = (self.fy, self.bilinear);
        let Some((top, bottom)) = self.columns.get_mut(side) else { return };
        self.grid.cell_values(column, self.rows.0, top);
        self.grid.cell_values(column, self.rows.1, bottom);
        if bilinear {
            let gy = 256 - fy;
            for (t, &b) in top.iter_mut().zip(bottom.iter()) {
                *t = gy.wrapping_mul(*t).wrapping_add(fy.wrapping_mul(b));
            }
        }
    }
}

/// A term: its mode, its slots, its channels and where its features start in the input vector.
#[derive(Clone, Copy)]
struct TermPlan {
    mode: TermMode,
    slots: usize,
    channels: usize,
    first: usize,
}

/// The input vectors of texels `(x, y)` of one mip, for any `x`; consecutive `x` are fast.
pub(super) struct SpanGather<'a, T> {
    mip_width: u32,
    mode: AddressMode,
    terms: heapless::Vec<TermPlan, MAX_TERMS>,
    slots: heapless::Vec<Slot<'a>, { MAX_TERMS * MAX_CHAIN }>,
    pe_frequencies: u8,
    input_frac_bits: u8,
    /// Where the positional encoding starts in the input vector.
    pe_first: usize,
    template: [T; MAX_WIDTH],
}

impl<'a, T: Feature> SpanGather<'a, T> {
    pub(super) fn new(material: &Material<'a>, y: i64, mip: u32) -> SpanGather<'a, T> {
        let (_, y, mip) = material.address_texel(0, y, mip);
        let (mip_width, mip_height) = material.mip_size(mip);
        let mode = material.address_mode;
        let mut terms = heapless::Vec::new();
        let mut slots = heapless::Vec::new();
        let mut first = 0;
        let level = material.levels.get(material.level_for_mip(mip));
        for term in level.map_or(&[][..], |l| l.terms.as_slice()) {
            let bilinear = term.mode == TermMode::Bilinear;
            let grid = |&g: &u8| material.grids.get(usize::from(g));
            let channels = term.grids.first().and_then(grid).map_or(0, LatentGrid::channels);
            // Nearest4 reads the first grid only; a bilinear term sums its whole chain.
            let chain =
                if bilinear { term.grids.as_slice() } else { term.grids.get(..1).unwrap_or(&[]) };
            let mut count = 0;
            for grid in chain.iter().filter_map(grid) {
                let height = grid.height().max(1);
                let (j, fy) = axis(y, mip_height, height);
                let slot = Slot {
                    grid: *grid,
                    bilinear,
                    rows: (address(j, height, mode), address(j + 1, height, mode)),
                    fy,
                    x_axis: AxisStepper::default(),
                    held: None,
                    columns: [([0; MAX_GRID_CHANNELS], [0; MAX_GRID_CHANNELS]); 2],
                };
                // Capacity: a level has at most MAX_TERMS terms of at most MAX_CHAIN grids.
                if slots.push(slot).is_ok() {
                    count += 1;
                }
            }
            let width = if bilinear { channels } else { 4 * channels * count };
            let _ = terms.push(TermPlan { mode: term.mode, slots: count, channels, first });
            first += width;
        }
        let f = material.mlp.input_frac_bits;
        let mut template = [T::default(); MAX_WIDTH];
        let feature = |v: i64| T::from_raw(v << RAW_SHIFT, f);
        let pe = template.get_mut(first..).unwrap_or(&mut []).chunks_exact_mut(4);
        for (k, features) in (0..material.mlp.pe_frequencies).zip(pe) {
            if let [_, _, y0, y1] = features {
                *y0 = feature(i64::from(triangle_q(y, k, 0, f)));
                *y1 = feature(i64::from(triangle_q(y, k, 1, f)));
            }
        }
        if material.mlp.lod_input {
            let lod = first + 4 * usize::from(material.mlp.pe_frequencies);
            if let Some(v) = template.get_mut(lod) {
                // mip / 16 in Q.f (f ≥ 4, mip ≤ 14), as in `Material::gather`.
                *v = feature(i64::from(mip << (f - 4)));
            }
        }
        SpanGather {
            mip_width,
            mode,
            terms,
            slots,
            pe_frequencies: material.mlp.pe_frequencies,
            input_frac_bits: f,
            pe_first: first,
            template,
        }
    }

    /// The input vector of texel `x` of the span's row into `io` (entries past the input width
    /// are 0).
    pub(super) fn inputs(&mut self, x: i64, io: &mut [T; MAX_WIDTH]) {
        let (mip_width, mode, f) = (self.mip_width, self.mode, self.input_frac_bits);
        let x = address(x, mip_width, mode);
        let template = &mut self.template;
        let mut slots = self.slots.iter_mut();
        for term in &self.terms {
            let features = template.get_mut(term.first..).unwrap_or(&mut []);
            let channels = term.channels;
            match term.mode {
                TermMode::Nearest4 => {
                    for slot in slots.by_ref().take(term.slots) {
                        if !slot.advance(x, mip_width, mode).1 {
                            continue;
                        }
                        let [(l0, l1), (r0, r1)] = &slot.columns;
                        let cells =
                            [l0, r0, l1, r1].into_iter().flat_map(|c| c.iter().take(channels));
                        for (v, &latent) in features.iter_mut().zip(cells) {
                            *v = T::from_raw(i64::from(latent) << RAW_SHIFT, f);
                        }
                    }
                }
                TermMode::Bilinear => {
                    let mut sums = [0i64; MAX_GRID_CHANNELS];
                    for slot in slots.by_ref().take(term.slots) {
                        let (fx, _) = slot.advance(x, mip_width, mode);
                        let gx = 256 - fx;
                        let [(left, _), (right, _)] = &slot.columns;
                        // By groups of 4 channels, as in `Material::gather`.
                        let quads = sums
                            .chunks_exact_mut(4)
                            .zip(left.chunks_exact(4))
                            .zip(right.chunks_exact(4))
                            .take(channels.div_ceil(4));
                        for ((sum, l), r) in quads {
                            for ((sum, &l), &r) in sum.iter_mut().zip(l).zip(r) {
                                let v = gx.wrapping_mul(l).wrapping_add(fx.wrapping_mul(r));
                                *sum += i64::from(v);
                            }
                        }
                    }
                    for (v, &sum) in features.iter_mut().zip(sums.iter().take(channels)) {
                        *v = T::from_raw(sum, f);
                    }
                }
            }
        }
        let pe = template.get_mut(self.pe_first..).unwrap_or(&mut []).chunks_exact_mut(4);
        for (k, features) in (0..self.pe_frequencies).zip(pe) {
            if let [x0, x1, _, _] = features {
                *x0 = T::from_raw(i64::from(triangle_q(x, k, 0, f)) << RAW_SHIFT, f);
                *x1 = T::from_raw(i64::from(triangle_q(x, k, 1, f)) << RAW_SHIFT, f);
            }
        }
        *io = *template;
    }
}
