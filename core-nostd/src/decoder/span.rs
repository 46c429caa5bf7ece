//! The input vectors of consecutive texels of one row (the gather of [`Decoder`] spans): the same
//! features, in the same order and to the bit, as `Material::gather` (FORMAT.md §6.2–§6.5), with
//! everything that does not change from texel to texel computed only when it changes.
//!
//! The span keeps an input vector (the template) between texels. Once per span: the addressed
//! row, each grid's two cell rows, vertical fraction and dequantization constants, and the
//! features of y (positional encoding, LOD) written into the template. Each distinct grid of the
//! level is one slot, however many chains use it. Per texel: each slot's x axis (stepped, not
//! divided); a new column of cells decoded only when the texel crosses into it, and a nearest
//! term's features rewritten only then; the bilinear features and the positional encoding of x;
//! then the template is copied out. A bilinear slot keeps its columns blended vertically
//! (`gy·top + fy·bottom`) as `base = 256·left` and `slope = right − left`, so its value at a
//! texel is `base + fx·slope` per channel: the definition's `Σ w·cell` exactly (the same
//! integer; intermediate wrapping cancels, as the sum lies in the i32 range the definition
//! states). Chain sums are split into `Σ (v >> 16)` and `Σ (v & 0xFFFF)`, both within i32.
//!
//! Everything past the latent features (the positional encoding and the LOD) repeats along the
//! row with the period of the encoding of x; `periodic_tail` and `fixed_inputs` let the decoder
//! fold that part into the first layer's sums once per span (`PeriodicSums` in `decoder/mod.rs`).
//!
//! [`Decoder`]: super::Decoder

use crate::decode::{Feature, RAW_SHIFT};
use crate::format::channel::AddressMode;
use crate::limits::{MAX_CHAIN, MAX_GRID_CHANNELS, MAX_TERMS, MAX_WIDTH};
use crate::material::{Material, Neural, TermMode};
use crate::neural::latents::{Dequantizer, LatentGrid, address, axis};
use crate::neural::posenc::triangle_q;

type Column = [i32; MAX_GRID_CHANNELS];

/// The x axis of a footprint ([`axis`]) for consecutive texels without a division per texel:
/// the numerator `(2x + 1)·grid·256` grows by a constant, so quotient and remainder by the
/// denominator `2·mip` are stepped exactly. Any other `x` is computed directly.
#[derive(Clone, Copy, Debug)]
struct XAxis {
    /// The texel the state is for, plus one: the texel that can be stepped to.
    next: Option<u32>,
    quotient: u64,
    remainder: u64,
    mip_width: u32,
    grid_width: u32,
    den: u64,
    step_quotient: u64,
    step_remainder: u64,
}

impl XAxis {
    fn new(mip_width: u32, grid_width: u32) -> XAxis {
        let den = 2 * u64::from(mip_width.max(1));
        let step = 2 * u64::from(grid_width) * 256;
        XAxis {
            next: None,
            quotient: 0,
            remainder: 0,
            mip_width,
            grid_width,
            den,
            step_quotient: step / den,
            step_remainder: step % den,
        }
    }

    /// `axis(x, mip_width, grid_width)`: the first cell index and the fraction in 1/256.
    #[inline(always)]
    fn at(&mut self, x: u32) -> (i64, i32) {
        if self.next == Some(x) {
            self.remainder += self.step_remainder;
            self.quotient += self.step_quotient;
            if self.remainder >= self.den {
                self.remainder -= self.den;
                self.quotient += 1;
            }
        } else {
            let num = (2 * u64::from(x) + 1) * u64::from(self.grid_width) * 256;
            (self.quotient, self.remainder) = (num / self.den, num % self.den);
        }
        self.next = x.checked_add(1);
        debug_assert_eq!(
            (self.quotient as i64 - 128) >> 8,
            axis(x, self.mip_width, self.grid_width).0
        );
        let pos = self.quotient as i64 - 128;
        (pos >> 8, (pos & 255) as i32)
    }
}

/// One grid of one term, for the row of the span.
#[derive(Clone, Copy)]
pub(super) struct Slot<'a> {
    /// The grid's number in the material, and whether it is sampled bilinearly.
    key: (u8, bool),
    grid: LatentGrid<'a>,
    /// The grid's dequantization, prepared.
    quant: Dequantizer,
    /// The two cell rows (addressed) and the vertical fraction in 1/256.
    rows: (u32, u32),
    fy: i32,
    x_axis: XAxis,
    /// The first cell index (before addressing) of the columns held, if any.
    held: Option<i64>,
    /// Left and right columns: (top, bottom) cells. For a bilinear grid only `columns[1].0` is
    /// used: the right column blended vertically (`gy·top + fy·bottom`).
    columns: [(Column, Column); 2],
    /// For a bilinear grid: `256·left` and `right − left` of the blended columns, so that a texel
    /// at fraction fx is `base + fx·slope` (= `(256 − fx)·left + fx·right`, wrapping like it).
    base: Column,
    slope: Column,
    /// After `advance`: whether the columns changed, and for a bilinear grid its value at the
    /// texel (`base + fx·slope`, per channel).
    changed: bool,
    value: Column,
}

impl<'a> Slot<'a> {
    /// Grid `grid` of a term, for row `y` of a `mip_size` mip.
    fn new(
        index: u8,
        grid: &LatentGrid<'a>,
        bilinear: bool,
        y: u32,
        mip_size: (u32, u32),
        mode: AddressMode,
    ) -> Slot<'a> {
        let (width, height) = (grid.width().max(1), grid.height().max(1));
        let (j, fy) = axis(y, mip_size.1, height);
        let quant = Dequantizer::new(grid);
        Slot {
            key: (index, bilinear),
            grid: *grid,
            quant,
            rows: (address(j, height, mode), address(j + 1, height, mode)),
            fy,
            x_axis: XAxis::new(mip_size.0, width),
            held: None,
            columns: [([0; MAX_GRID_CHANNELS], [0; MAX_GRID_CHANNELS]); 2],
            base: [0; MAX_GRID_CHANNELS],
            slope: [0; MAX_GRID_CHANNELS],
            changed: false,
            value: [0; MAX_GRID_CHANNELS],
        }
    }

    fn bilinear(&self) -> bool {
        self.key.1
    }

    /// Steps to texel `x`: sets `changed`, and for a bilinear grid `value`.
    #[inline(always)]
    fn advance(&mut self, x: u32, mode: AddressMode) {
        let (i, fx) = self.x_axis.at(x);
        self.changed = self.held != Some(i);
        if self.changed {
            self.enter(i, mode);
        }
        if self.bilinear() {
            // All 16 lanes (unused ones are 0): fixed-length, one or a few vector operations.
            let lanes = self.value.iter_mut().zip(&self.base).zip(&self.slope);
            for ((v, &b), &s) in lanes {
                *v = b.wrapping_add(fx.wrapping_mul(s));
            }
        }
    }

    /// Loads the columns of first cell index `i` (reusing the right one when it moves by one).
    /// The lanes past the grid's channels are 0 and stay 0. Inlined into the kernel's
    /// code (compiled for its instruction set, as the dequantization's 16 lanes need).
    #[inline(always)]
    fn enter(&mut self, i: i64, mode: AddressMode) {
        let width = self.grid.width().max(1);
        let step = self.held == Some(i - 1);
        self.held = Some(i);
        if self.bilinear() {
            // Only the blended columns are kept: `columns[1].0` is the right one.
            let left = if step { self.columns[1].0 } else { self.blended(address(i, width, mode)) };
            let right = self.blended(address(i + 1, width, mode));
            // All 16 lanes (those past the channels are 0 in both columns, and stay 0).
            let lanes = self.base.iter_mut().zip(&mut self.slope).zip(&left).zip(&right);
            for (((b, s), &l), &r) in lanes {
                *b = l.wrapping_mul(256);
                *s = r.wrapping_sub(l);
            }
            self.columns[1].0 = right;
            return;
        }
        let [(l0, l1), (r0, r1)] = &mut self.columns;
        if step {
            l0.copy_from_slice(r0);
            l1.copy_from_slice(r1);
        } else {
            let column = address(i, width, mode);
            cell_values(&self.grid, &self.quant, column, self.rows.0, l0);
            cell_values(&self.grid, &self.quant, column, self.rows.1, l1);
        }
        let column = address(i + 1, width, mode);
        cell_values(&self.grid, &self.quant, column, self.rows.0, r0);
        cell_values(&self.grid, &self.quant, column, self.rows.1, r1);
    }

    /// The column of cells `column` blended vertically: `gy·top + fy·bottom` per channel.
    #[inline(always)]
    fn blended(&self, column: u32) -> Column {
        let (mut top, mut bottom) = ([0; MAX_GRID_CHANNELS], [0; MAX_GRID_CHANNELS]);
        cell_values(&self.grid, &self.quant, column, self.rows.0, &mut top);
        cell_values(&self.grid, &self.quant, column, self.rows.1, &mut bottom);
        let (fy, gy) = (self.fy, 256 - self.fy);
        // All 16 lanes: those past the grid's channels are 0 in both cells.
        for (t, &b) in top.iter_mut().zip(&bottom) {
            *t = gy.wrapping_mul(*t).wrapping_add(fy.wrapping_mul(b));
        }
        top
    }
}

/// [`LatentGrid::cell_values`] with the dequantization prepared: the grid's channels, and 0 in
/// the lanes past them where the cell's codes fit one window (else those lanes are left alone).
#[inline(always)]
fn cell_values(grid: &LatentGrid<'_>, quant: &Dequantizer, x: u32, y: u32, out: &mut Column) {
    match grid.cells_window(x, y, 1) {
        Some(window) => quant.cell(window, 0, out),
        None => grid.cell_values(x, y, out),
    }
}

/// A term: its mode, its grids (as slot numbers), its channels and where its features start in
/// the input vector.
#[derive(Clone)]
struct TermPlan {
    mode: TermMode,
    chain: heapless::Vec<usize, MAX_CHAIN>,
    channels: usize,
    first: usize,
}

/// Room for the slots of one span, declared by the caller (on its stack: no allocation, and
/// nothing to move — the room for every possible slot is tens of KiB).
pub(super) type Slots<'a> = heapless::Vec<Slot<'a>, { MAX_TERMS * MAX_CHAIN }>;

/// The input vectors of texels `(x, y)` of one mip, for any `x`; consecutive `x` are fast.
pub(super) struct SpanGather<'s, 'a, T> {
    mip_width: u32,
    mode: AddressMode,
    terms: heapless::Vec<TermPlan, MAX_TERMS>,
    /// One slot per grid and sampling mode: a grid in several chains (NBC's feature reuse) is
    /// stepped and blended once per texel.
    slots: &'s mut Slots<'a>,
    pe_frequencies: u8,
    input_frac_bits: u8,
    /// Where the positional encoding starts in the input vector.
    pe_first: usize,
    /// The input width in chunks of 32 entries.
    chunks: usize,
    template: [T; MAX_WIDTH],
    /// The x features (phase 0, phase 1 of each frequency) of texels 0 … `x_period` − 1, or
    /// `x_period` 0 when the period is too long to tabulate.
    x_table: [T; X_TABLE],
    x_period: u32,
}

/// Frequencies up to which the encoding of x is tabulated: a period of at most 32 texels.
const X_TABLE_FREQUENCIES: u8 = 4;
/// The longest tabulated period of the encoding of x, in texels.
pub(super) const MAX_X_PERIOD: usize = 2 << X_TABLE_FREQUENCIES;
/// Entries of the table: 2 per frequency per texel of the period.
const X_TABLE: usize = 2 * X_TABLE_FREQUENCIES as usize * MAX_X_PERIOD;

impl<'s, 'a, T: Feature> SpanGather<'s, 'a, T> {
    /// The gather of row `y` of `mip` of `material`, whose model is `n`, keeping its slots in
    /// `slots` (emptied first).
    pub(super) fn new(
        material: &Material<'a>,
        n: &Neural<'a>,
        y: i64,
        mip: u32,
        slots: &'s mut Slots<'a>,
    ) -> SpanGather<'s, 'a, T> {
        let (_, y, mip) = material.address_texel(0, y, mip);
        let (mip_width, mip_height) = material.mip_size(mip);
        let mode = material.address_mode;
        let mut terms = heapless::Vec::new();
        slots.clear();
        let mut first = 0;
        let level = n.levels.get(n.level_for_mip(mip));
        for term in level.map_or(&[][..], |l| l.terms.as_slice()) {
            let bilinear = term.mode == TermMode::Bilinear;
            let grid_of = |g: u8| n.grids.get(usize::from(g));
            let channels = term.grids.first().and_then(|&g| grid_of(g)).map_or(0, |g| g.channels());
            // Nearest4 reads the first grid only; a bilinear term sums its whole chain.
            let grids =
                if bilinear { term.grids.as_slice() } else { term.grids.get(..1).unwrap_or(&[]) };
            let mut chain = heapless::Vec::new();
            for &g in grids {
                let Some(grid) = grid_of(g) else { continue };
                let known = slots.iter().position(|s| s.key == (g, bilinear));
                let index = match known {
                    Some(i) => i,
                    None => {
                        let slot = Slot::new(g, grid, bilinear, y, (mip_width, mip_height), mode);
                        // Capacity: a level has at most MAX_TERMS terms of at most MAX_CHAIN
                        // grids, so at most that many distinct slots.
                        let _ = slots.push(slot);
                        slots.len() - 1
                    }
                };
                let _ = chain.push(index);
            }
            let width = if bilinear { channels } else { 4 * channels * chain.len() };
            let _ = terms.push(TermPlan { mode: term.mode, chain, channels, first });
            first += width;
        }
        let f = n.mlp.input_frac_bits;
        let mut template = [T::default(); MAX_WIDTH];
        let feature = |v: i64| T::from_raw(v << RAW_SHIFT, f);
        let pe = template.get_mut(first..).unwrap_or(&mut []).chunks_exact_mut(4);
        for (k, features) in (0..n.mlp.pe_frequencies).zip(pe) {
            if let [_, _, y0, y1] = features {
                *y0 = feature(i64::from(triangle_q(y, k, 0, f)));
                *y1 = feature(i64::from(triangle_q(y, k, 1, f)));
            }
        }
        // The encoding of x repeats every 2^(K+1) texels (K frequencies, periods 4 … 2^(K+1)):
        // for K ≤ X_TABLE_FREQUENCIES one period is tabulated and looked up by x's low bits.
        let frequencies = n.mlp.pe_frequencies;
        let mut x_table = [T::default(); X_TABLE];
        let x_period = if frequencies <= X_TABLE_FREQUENCIES { 2u32 << frequencies } else { 0 };
        let per_texel = 2 * usize::from(frequencies);
        for (x, row) in (0..x_period).zip(x_table.chunks_exact_mut(per_texel.max(1))) {
            for (k, pair) in (0..frequencies).zip(row.chunks_exact_mut(2)) {
                for (phase, v) in (0..2).zip(pair) {
                    *v = feature(i64::from(triangle_q(x, k, phase, f)));
                }
            }
        }
        if let Some(q) = n.mlp.lod_feature(mip) {
            let lod = first + 4 * usize::from(n.mlp.pe_frequencies);
            if let Some(v) = template.get_mut(lod) {
                *v = feature(i64::from(q));
            }
        }
        SpanGather {
            mip_width,
            mode,
            terms,
            slots,
            pe_frequencies: n.mlp.pe_frequencies,
            input_frac_bits: f,
            pe_first: first,
            chunks: n.mlp.layers.first().map_or(0, |l| l.inputs()).div_ceil(32),
            template,
            x_table,
            x_period,
        }
    }

    /// The input vector of texel `x` of the span's row into `io` (entries past the input width
    /// are 0). Returns the addressed x.
    #[inline(always)]
    pub(super) fn inputs(&mut self, x: i64, io: &mut [T; MAX_WIDTH]) -> u32 {
        let (mode, f) = (self.mode, self.input_frac_bits);
        let x = address(x, self.mip_width, mode);
        for slot in self.slots.iter_mut() {
            slot.advance(x, mode);
        }
        let template = &mut self.template;
        for term in &self.terms {
            let features = template.get_mut(term.first..).unwrap_or(&mut []);
            let channels = term.channels;
            let mut chain = term.chain.iter().filter_map(|&i| self.slots.get(i));
            match term.mode {
                TermMode::Nearest4 => {
                    let Some(slot) = chain.next().filter(|s| s.changed) else { continue };
                    let [(l0, l1), (r0, r1)] = &slot.columns;
                    let places = features.chunks_exact_mut(channels.max(1));
                    for (cell, places) in [l0, r0, l1, r1].into_iter().zip(places) {
                        let lanes: [T; MAX_GRID_CHANNELS] = core::array::from_fn(|c| {
                            T::from_latent(cell.get(c).map_or(0, |&v| v), f)
                        });
                        write_lanes(places, &lanes);
                    }
                }
                TermMode::Bilinear if term.chain.len() == 1 => {
                    // One grid (NTC): its value is within [−2^31, 2^31 − 2^16] (the definition's
                    // bound), so the rounding add stays in i32.
                    let Some(slot) = chain.next() else { continue };
                    let places = features.get_mut(..channels).unwrap_or(&mut []);
                    write_lanes(places, &bilinear_lanes(&slot.value, f));
                }
                TermMode::Bilinear => {
                    // The chain's sum split as Σ(v >> 16)·2^16 + Σ(v & 0xFFFF): both parts stay
                    // in i32 for any chain (≤ 8 grids), so all 16 lanes add without widening.
                    let (mut high, mut low) =
                        ([0i32; MAX_GRID_CHANNELS], [0i32; MAX_GRID_CHANNELS]);
                    for slot in chain {
                        for ((h, l), &v) in high.iter_mut().zip(&mut low).zip(&slot.value) {
                            *h += v >> RAW_SHIFT;
                            *l += v & 0xFFFF;
                        }
                    }
                    let places = features.get_mut(..channels).unwrap_or(&mut []);
                    write_lanes(places, &from_parts_lanes(&high, &low, f));
                }
            }
        }
        let pe = template.get_mut(self.pe_first..).unwrap_or(&mut []);
        write_x_features(&self.x_table, self.x_period, self.pe_frequencies, f, x, pe);
        // The input width rounded up to 32 entries, in chunks of a size known at compile time
        // (copied without a call).
        let (to, _) = io.as_chunks_mut::<32>();
        let (from, _) = template.as_chunks::<32>();
        for (to, from) in to.iter_mut().zip(from).take(self.chunks) {
            *to = *from;
        }
        x
    }

    /// The input pairs at the front that texels share — those of a first `Nearest4` term, whose
    /// features change only where a texel enters another cell — and the slot whose
    /// [`SpanGather::changed`] says so, when its grid has at most half as many cells across as
    /// the mip has texels (so that each cell serves two texels or more of the row).
    pub(super) fn shared_pairs(&self) -> Option<(usize, usize)> {
        let term = self.terms.first().filter(|t| t.mode == TermMode::Nearest4)?;
        let &slot = term.chain.first()?;
        let grid_width = self.slots.get(slot)?.grid.width();
        // 4 cells of `channels` features each (an even count), from input 0.
        (2 * u64::from(grid_width) <= u64::from(self.mip_width))
            .then_some((2 * term.channels, slot))
    }

    /// Whether the texel of the last [`SpanGather::inputs`] entered another cell of `slot`'s
    /// grid; true for the span's first texel.
    #[inline(always)]
    pub(super) fn changed(&self, slot: usize) -> bool {
        self.slots.get(slot).is_some_and(|s| s.changed)
    }

    /// How many leading inputs depend on x other than through its positional encoding (the
    /// latent features), if the encoding of x repeats with a tabulated period: then the rest of
    /// the input vector of texel x is [`SpanGather::fixed_inputs`] of `x % period`.
    pub(super) fn periodic_tail(&self) -> Option<(usize, u32)> {
        (self.x_period > 0).then_some((self.pe_first, self.x_period))
    }

    /// The input vector of any texel whose addressed x is `phase` modulo the period, with the
    /// latent features (the first `periodic_tail().0` entries) set to 0.
    pub(super) fn fixed_inputs(&self, phase: u32, io: &mut [T; MAX_WIDTH]) {
        *io = self.template;
        let (latents, pe) = io.split_at_mut(self.pe_first.min(MAX_WIDTH));
        latents.fill(T::default());
        let f = self.input_frac_bits;
        write_x_features(&self.x_table, self.x_period, self.pe_frequencies, f, phase, pe);
    }
}

/// [`Feature::from_parts`] of all 16 lanes (fixed-length, vector code for i16).
#[inline(always)]
pub(super) fn from_parts_lanes<T: Feature>(
    high: &[i32; MAX_GRID_CHANNELS],
    low: &[i32; MAX_GRID_CHANNELS],
    f: u8,
) -> [T; MAX_GRID_CHANNELS] {
    let mut lanes = [T::default(); MAX_GRID_CHANNELS];
    for ((v, &h), &l) in lanes.iter_mut().zip(high).zip(low) {
        *v = T::from_parts(h, l, f);
    }
    lanes
}

/// The features of one grid's bilinear values in all 16 lanes: [`Feature::from_bilinear`].
#[inline(always)]
pub(super) fn bilinear_lanes<T: Feature>(
    values: &[i32; MAX_GRID_CHANNELS],
    f: u8,
) -> [T; MAX_GRID_CHANNELS] {
    let mut lanes = [T::default(); MAX_GRID_CHANNELS];
    for (v, &value) in lanes.iter_mut().zip(values) {
        *v = T::from_bilinear(value, f);
    }
    lanes
}

/// The first `places.len()` (at most 16) of `lanes` into `places`, with moves of a length known
/// at compile time (two overlapping ones of 8 or 4 entries) rather than one per entry.
#[inline(always)]
pub(super) fn write_lanes<T: Copy>(places: &mut [T], lanes: &[T; MAX_GRID_CHANNELS]) {
    fn both<T: Copy, const N: usize>(places: &mut [T], lanes: &[T; MAX_GRID_CHANNELS]) {
        let n = places.len();
        let (Some(head), Some(from)) = (places.first_chunk_mut::<N>(), lanes.first_chunk::<N>())
        else {
            return;
        };
        *head = *from;
        let tail = places.last_chunk_mut::<N>();
        let from = lanes.get(n - N..n).and_then(|l| l.first_chunk::<N>());
        if let (Some(tail), Some(from)) = (tail, from) {
            *tail = *from;
        }
    }
    match places.len() {
        8..=MAX_GRID_CHANNELS => both::<T, 8>(places, lanes),
        4..=7 => both::<T, 4>(places, lanes),
        _ => {
            for (v, &lane) in places.iter_mut().zip(lanes) {
                *v = lane;
            }
        }
    }
}

/// The positional encoding of x into the (x0, x1, y0, y1) groups of `pe`: looked up in the
/// one-period `table` when `period` > 0, computed otherwise.
#[inline(always)]
fn write_x_features<T: Feature>(
    table: &[T; X_TABLE],
    period: u32,
    frequencies: u8,
    f: u8,
    x: u32,
    pe: &mut [T],
) {
    let pe = pe.chunks_exact_mut(4);
    if period > 0 {
        let per_texel = 2 * usize::from(frequencies);
        let at = (x & (period - 1)) as usize * per_texel;
        let row = table.get(at..at + per_texel).unwrap_or(&[]).chunks_exact(2);
        for (features, pair) in pe.zip(row) {
            if let ([x0, x1, _, _], [v0, v1]) = (features, pair) {
                (*x0, *x1) = (*v0, *v1);
            }
        }
    } else {
        for (k, features) in (0..frequencies).zip(pe) {
            if let [x0, x1, _, _] = features {
                *x0 = T::from_raw(i64::from(triangle_q(x, k, 0, f)) << RAW_SHIFT, f);
                *x1 = T::from_raw(i64::from(triangle_q(x, k, 1, f)) << RAW_SHIFT, f);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every length from 0 to 16 is written exactly: its entries, nothing after them.
    #[test]
    fn write_lanes_writes_exactly_the_places() {
        let lanes: [i16; MAX_GRID_CHANNELS] = core::array::from_fn(|i| i as i16 + 1);
        for n in 0..=MAX_GRID_CHANNELS {
            let mut out = [-1i16; 20];
            write_lanes(&mut out[..n], &lanes);
            assert_eq!(out[..n], lanes[..n], "length {n}");
            assert!(out[n..].iter().all(|&v| v == -1), "length {n}");
        }
    }

    /// Stepping equals dividing for every texel, with grids finer and coarser than the mip, and
    /// restarts correctly after a jump.
    #[test]
    fn x_axis_steps_like_axis() {
        for mip in [1u32, 2, 3, 7, 40, 97, 16384] {
            for grid in [1u32, 2, 5, 33, 64, 70, 4096, 16384] {
                let mut s = XAxis::new(mip, grid);
                let xs =
                    (0..mip.min(300)).chain([0, 5, 6, 2, 3, 4].into_iter().filter(|&x| x < mip));
                for x in xs {
                    assert_eq!(s.at(x), axis(x, mip, grid), "mip {mip} grid {grid} x {x}");
                }
            }
        }
    }
}
