//! The input vectors of single texels (the gather of [`Decoder::decode_texel_u8`] and of scattered
//! texels, [`Decoder::decode_texels_u8`]): the same features, in the same order and to the bit, as
//! `Material::gather` (FORMAT.md §6.2–§6.5), with what does not depend on the texel prepared once
//! per decoder: each grid's dequantization constants, and each level's plan — the grids it reads
//! (each once, however many terms use it), where each one's features go in the input vector.
//!
//! Per texel: each grid's footprint and its cells' codes read (all grids, and for a group all
//! texels, before any value is computed, so that cache misses overlap), the 4 cells dequantized
//! once, written out as the `Nearest4` features of a term that reads the grid that way, weighted
//! bilinearly once where a term samples it, the chains summed, then the positional encoding and
//! the LOD.
//!
//! [`Decoder::decode_texel_u8`]: super::Decoder::decode_texel_u8
//! [`Decoder::decode_texels_u8`]: super::Decoder::decode_texels_u8

extern crate alloc;

use alloc::vec::Vec;

use crate::decode::{Feature, RAW_SHIFT, Reads, TexelReads, weighted};
use crate::decoder::TexelAt;
use crate::decoder::span::{bilinear_lanes, from_parts_lanes, write_lanes};
use crate::limits::{MAX_CHAIN, MAX_GRID_CHANNELS, MAX_GRIDS, MAX_TERMS, MAX_WIDTH};
use crate::material::{Material, Neural, TermMode};
use crate::neural::latents::Dequantizer;
use crate::neural::posenc::{PE_LANES, PeLanes};

/// One grid a level reads.
#[derive(Clone, Debug)]
struct SlotPlan {
    /// The grid's number in the material.
    grid: u8,
    /// Where its 4 cells go as a `Nearest4` term's features (their first input), for each term
    /// that reads it that way.
    nearest: heapless::Vec<usize, MAX_TERMS>,
    /// Whether a bilinear term samples it.
    bilinear: bool,
}

/// A bilinear term: the slots of its chain, its channels and its first input.
#[derive(Clone, Debug)]
struct ChainPlan {
    slots: heapless::Vec<u8, MAX_CHAIN>,
    channels: usize,
    first: usize,
}

/// One feature level: its slots in the order the definition first reads them, its bilinear
/// terms, and where the positional encoding starts.
#[derive(Clone, Debug, Default)]
struct LevelPlan {
    slots: heapless::Vec<SlotPlan, MAX_GRIDS>,
    chains: heapless::Vec<ChainPlan, MAX_TERMS>,
    /// How many `Nearest4` terms the level has.
    nearest_terms: usize,
    pe_first: usize,
}

/// What the gather of single texels prepares of a neural material (see the module documentation).
#[derive(Clone, Debug)]
pub(super) struct TexelPlan {
    /// Per grid of the material.
    quant: Vec<Dequantizer>,
    /// Per feature level of the material.
    levels: Vec<LevelPlan>,
    /// The positional encoding.
    pe: PeLanes,
}

impl TexelPlan {
    pub(super) fn new(n: &Neural<'_>) -> TexelPlan {
        let quant = n.grids.iter().map(Dequantizer::new).collect();
        let levels = n.levels.iter().map(|level| level_plan(n, &level.terms)).collect();
        let (frequencies, f) = (n.mlp.pe_frequencies, n.mlp.input_frac_bits);
        let pe = PeLanes::new(frequencies, f);
        TexelPlan { quant, levels, pe }
    }

    /// The footprints of an (addressed) texel on every grid its level reads, and their cells'
    /// codes, into `reads` (emptied first), in the order of the level's slots.
    #[inline(always)]
    fn read(
        &self,
        m: &Material<'_>,
        n: &Neural<'_>,
        texel: (u32, u32, u32),
        reads: &mut TexelReads,
    ) {
        reads.clear();
        let (x, y, mip) = texel;
        let Some(level) = self.levels.get(n.level_for_mip(mip)) else { return };
        let mip_size = m.mip_size(mip);
        for slot in &level.slots {
            if let Some(grid) = n.grids.get(usize::from(slot.grid)) {
                // At most MAX_GRIDS slots.
                let _ = reads.push(Reads::new(slot.grid, grid, (x, y), mip_size, m.address_mode));
            }
        }
    }

    /// The input vector of an (addressed) texel into `io`, from its codes as
    /// [`TexelPlan::read`] read them; entries past the input width are 0.
    #[inline(always)]
    fn assemble<T: Feature>(
        &self,
        n: &Neural<'_>,
        (x, y, mip): (u32, u32, u32),
        reads: &TexelReads,
        io: &mut [T; MAX_WIDTH],
    ) {
        *io = [T::default(); MAX_WIDTH];
        let Some(level) = self.levels.get(n.level_for_mip(mip)) else { return };
        let f = n.mlp.input_frac_bits;
        // The bilinear value of each slot a term samples (0 for the others), by slot.
        let mut values = heapless::Vec::<[i32; MAX_GRID_CHANNELS], MAX_GRIDS>::new();
        for (slot, r) in level.slots.iter().zip(reads) {
            let (Some(grid), Some(quant)) =
                (n.grids.get(usize::from(slot.grid)), self.quant.get(usize::from(slot.grid)))
            else {
                let _ = values.push([0; MAX_GRID_CHANNELS]);
                continue;
            };
            let channels = grid.channels();
            // Lanes past the grid's channels stay 0, as `weighted` needs.
            let mut cells = [[0; MAX_GRID_CHANNELS]; 4];
            r.cells_prepared(grid, quant, &mut cells);
            for &first in &slot.nearest {
                // One nearest term in the level: each cell written as 16 lanes, the lanes past the
                // channels (0) landing on inputs written after it (the next cells, the bilinear
                // terms, the encoding) or past the inputs (which stay 0), when that stays inside.
                if level.nearest_terms == 1 && first + 3 * channels + MAX_GRID_CHANNELS <= MAX_WIDTH
                {
                    for (k, cell) in cells.iter().enumerate() {
                        let at = first + k * channels;
                        let places = io.get_mut(at..).and_then(|p| p.first_chunk_mut::<16>());
                        if let Some(places) = places {
                            for (v, &latent) in places.iter_mut().zip(cell) {
                                *v = T::from_latent(latent, f);
                            }
                        }
                    }
                    continue;
                }
                let places = io.get_mut(first..).unwrap_or(&mut []).chunks_mut(channels.max(1));
                for (cell, places) in cells.iter().zip(places) {
                    for (v, &latent) in places.iter_mut().zip(cell) {
                        *v = T::from_latent(latent, f);
                    }
                }
            }
            // All 16 lanes (fixed-length, vector code): those past the channels are 0 in the cells.
            let value = if slot.bilinear {
                weighted(&cells, r, MAX_GRID_CHANNELS)
            } else {
                [0; MAX_GRID_CHANNELS]
            };
            let _ = values.push(value);
        }
        for chain in &level.chains {
            let end = chain.first + chain.channels;
            let places = io.get_mut(chain.first..end).unwrap_or(&mut []);
            if let &[slot] = chain.slots.as_slice()
                && let Some(value) = values.get(usize::from(slot))
            {
                // One grid (NTC): as in the span gather, the rounding stays in i32.
                write_lanes(places, &bilinear_lanes(value, f));
                continue;
            }
            // The chain's sum split as Σ(v >> 16)·2^16 + Σ(v & 0xFFFF), both in i32 for any chain
            // (≤ 8 grids): all 16 lanes add without widening (as in the span gather).
            let (mut high, mut low) = ([0i32; MAX_GRID_CHANNELS], [0i32; MAX_GRID_CHANNELS]);
            for value in chain.slots.iter().filter_map(|&s| values.get(usize::from(s))) {
                for ((h, l), &v) in high.iter_mut().zip(&mut low).zip(value) {
                    *h += v >> RAW_SHIFT;
                    *l += v & 0xFFFF;
                }
            }
            write_lanes(places, &from_parts_lanes(&high, &low, f));
        }
        // A wave's value is below 2^14: on the input grid already, like a latent. All lanes are
        // written where they fit: those past the encoding (0) land on the LOD, written after,
        // or past the inputs.
        let features = self.pe.at(x, y);
        let lod = level.pe_first + 4 * usize::from(n.mlp.pe_frequencies);
        match io.get_mut(level.pe_first..).and_then(|p| p.first_chunk_mut::<PE_LANES>()) {
            Some(places) => {
                for (v, &q) in places.iter_mut().zip(&features) {
                    *v = T::from_latent(q, f);
                }
            }
            None => {
                let places = io.get_mut(level.pe_first..lod).unwrap_or(&mut []);
                for (v, &q) in places.iter_mut().zip(&features) {
                    *v = T::from_latent(q, f);
                }
            }
        }
        if let (Some(q), Some(v)) = (n.mlp.lod_feature(mip), io.get_mut(lod)) {
            *v = T::from_raw(i64::from(q) << RAW_SHIFT, f);
        }
    }

    /// The input vector of texel (x, y) of `mip` (unaddressed) into `io`.
    #[inline(always)]
    pub(super) fn inputs<T: Feature>(
        &self,
        m: &Material<'_>,
        n: &Neural<'_>,
        (x, y, mip): (i64, i64, u32),
        io: &mut [T; MAX_WIDTH],
    ) {
        let texel = m.address_texel(x, y, mip);
        let mut reads = TexelReads::new();
        self.read(m, n, texel, &mut reads);
        self.assemble(n, texel, &reads, io);
    }

    /// [`TexelPlan::inputs`] of up to `G` texels into `ios`, one each: every texel's codes read
    /// before any texel's inputs are computed, so their cache misses overlap.
    #[inline(always)]
    pub(super) fn inputs_group<T: Feature, const G: usize>(
        &self,
        m: &Material<'_>,
        n: &Neural<'_>,
        texels: &[TexelAt],
        ios: &mut [[T; MAX_WIDTH]; G],
    ) {
        let mut at = [(0, 0, 0); G];
        let mut reads: [TexelReads; G] = core::array::from_fn(|_| TexelReads::new());
        for ((a, r), t) in at.iter_mut().zip(&mut reads).zip(texels) {
            *a = m.address_texel(t.x, t.y, t.mip);
            self.read(m, n, *a, r);
        }
        for ((io, r), &texel) in ios.iter_mut().zip(&reads).zip(&at).take(texels.len()) {
            self.assemble(n, texel, r, io);
        }
    }
}

/// The plan of a level of `terms`, placing features as `Material::gather` pushes them: a
/// `Nearest4` term 4 cells of its first grid's channels, a bilinear term its first grid's
/// channels (summed over its chain), then the positional encoding and the LOD.
fn level_plan(n: &Neural<'_>, terms: &[crate::material::Term]) -> LevelPlan {
    let mut plan = LevelPlan::default();
    let mut first = 0;
    for term in terms {
        let channels = term
            .grids
            .first()
            .and_then(|&g| n.grids.get(usize::from(g)))
            .map_or(0, |g| g.channels());
        let grids = match term.mode {
            TermMode::Nearest4 => term.grids.get(..1).unwrap_or(&[]),
            TermMode::Bilinear => term.grids.as_slice(),
        };
        let mut chain = heapless::Vec::new();
        for &g in grids.iter().filter(|&&g| n.grids.get(usize::from(g)).is_some()) {
            let index = match plan.slots.iter().position(|s| s.grid == g) {
                Some(i) => i,
                None => {
                    // A level reads at most MAX_GRIDS grids.
                    let slot = SlotPlan { grid: g, nearest: heapless::Vec::new(), bilinear: false };
                    let _ = plan.slots.push(slot);
                    plan.slots.len() - 1
                }
            };
            if let Some(slot) = plan.slots.get_mut(index) {
                match term.mode {
                    TermMode::Nearest4 => {
                        let _ = slot.nearest.push(first);
                    }
                    TermMode::Bilinear => slot.bilinear = true,
                }
            }
            let _ = chain.push(index as u8);
        }
        match term.mode {
            // The definition pushes a nearest term's cells only when its grid exists.
            TermMode::Nearest4 => {
                plan.nearest_terms += 1;
                first += 4 * channels * chain.len();
            }
            TermMode::Bilinear => {
                let _ = plan.chains.push(ChainPlan { slots: chain, channels, first });
                first += channels;
            }
        }
    }
    plan.pe_first = first;
    plan
}
