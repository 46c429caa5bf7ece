//! Latent grids: bit-packed codes, their dequantization, and where a texel lands on a grid
//! (docs/FORMAT.md §4 and §6.2).

use crate::bytes::{arr, i16_at, u32_at};
use crate::format::channel::AddressMode;
#[cfg(feature = "alloc")]
use crate::limits::MAX_GRID_CHANNELS;

/// A validated view of one latent grid inside the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LatentGrid<'a> {
    pub(crate) width: u16,
    pub(crate) height: u16,
    pub(crate) channels: u8,
    pub(crate) bits: u8,
    /// `channels` × (offset: i16, step: i16), little-endian.
    pub(crate) quant: &'a [u8],
    /// The packed 32-bit words, exactly `packed_len` bytes.
    pub(crate) data: &'a [u8],
}

/// Bytes of the packed data of a grid: whole 32-bit words (FORMAT.md §4). `None` on overflow.
pub fn packed_len(width: u32, height: u32, channels: u32, bits: u32) -> Option<usize> {
    let total_bits = u64::from(width)
        .checked_mul(u64::from(height))?
        .checked_mul(u64::from(channels))?
        .checked_mul(u64::from(bits))?;
    let words = total_bits.checked_add(31)? / 32;
    usize::try_from(words.checked_mul(4)?).ok()
}

impl<'a> LatentGrid<'a> {
    pub fn width(&self) -> u32 {
        u32::from(self.width)
    }
    pub fn height(&self) -> u32 {
        u32::from(self.height)
    }
    pub fn channels(&self) -> usize {
        usize::from(self.channels)
    }
    pub fn bits_per_latent(&self) -> u32 {
        u32::from(self.bits)
    }
    /// The packed words as stored (little-endian u32s), ready to upload to a GPU buffer.
    pub fn packed_data(&self) -> &'a [u8] {
        self.data
    }
    /// `(offset, step)` of channel `c` in input Q-format units: value = offset + code · step.
    pub fn quantization(&self, c: usize) -> (i16, i16) {
        (i16_at(self.quant, 4 * c), i16_at(self.quant, 4 * c + 2))
    }

    /// The stored code of cell (x, y), channel c. Out-of-range arguments read as 0.
    pub fn code(&self, x: u32, y: u32, c: usize) -> u8 {
        if x >= self.width() || y >= self.height() || c >= self.channels() {
            return 0;
        }
        let index = (u64::from(y) * u64::from(self.width) + u64::from(x))
            * u64::from(self.channels)
            + c as u64;
        let bit = index * u64::from(self.bits);
        let word = (bit / 32) as usize;
        // A latent may straddle two words; the second read is past the end only when it does not.
        let lo = u64::from(u32_at(self.data, word * 4));
        let hi = u64::from(u32_at(self.data, word * 4 + 4));
        let both = (hi << 32) | lo;
        let mask = (1u64 << self.bits) - 1;
        ((both >> (bit % 32)) & mask) as u8
    }

    /// The dequantized values of every channel of cell (x, y) into `out` (further entries are
    /// left alone): the cell's codes are consecutive bits, read with one index computation.
    /// Out-of-range cells read as codes 0.
    pub fn cell_values(&self, x: u32, y: u32, out: &mut [i32]) {
        if let Some(codes) = self.cells_window(x, y, 1) {
            // The common case: every code of the cell in one 64-bit read.
            self.dequantize(codes, out);
            return;
        }
        let quant = self.quant.chunks_exact(4).map(|q| match *q {
            [o0, o1, s0, s1] => {
                (i32::from(i16::from_le_bytes([o0, o1])), i32::from(i16::from_le_bytes([s0, s1])))
            }
            _ => (0, 0),
        });
        let bits = u32::from(self.bits);
        let mask = (1u64 << bits) - 1;
        let inside = x < self.width() && y < self.height();
        let cell = u64::from(y) * u64::from(self.width) + u64::from(x);
        let first = cell * u64::from(self.channels) * u64::from(bits);
        // Read 64 bits at the first latent's word: with ≤ 8-bit latents, every latent starting
        // within the first 56 bits past it (bits 0–31 of the word + up to 3 more bytes) lies
        // inside them; further latents start a new window. Bytes past the data read as 0, as
        // in `code` (only latents ending inside the data are real).
        let mut window_start = u64::MAX;
        let mut window = 0u64;
        for (c, (slot, (offset, step))) in out.iter_mut().zip(quant).enumerate() {
            let bit = first + c as u64 * u64::from(bits);
            let code = if inside {
                if bit + u64::from(bits) > window_start.saturating_add(64) || bit < window_start {
                    window_start = bit & !31;
                    let word = (window_start / 32) as usize * 4;
                    window = u64::from(u32_at(self.data, word))
                        | u64::from(u32_at(self.data, word + 4)) << 32;
                }
                (window >> (bit - window_start)) & mask
            } else {
                0
            };
            *slot = offset + code as i32 * step;
        }
    }

    /// The values of two consecutive cells from the codes of [`LatentGrid::cells_window`]`(…, 2)`.
    #[inline]
    pub(crate) fn dequantize_pair(&self, codes: u64, out: (&mut [i32], &mut [i32])) {
        let rest = self.dequantize(codes, out.0);
        self.dequantize(rest, out.1);
    }

    /// Dequantizes the codes of one cell, lowest bits first, into `out`; returns the bits left.
    #[inline]
    pub(crate) fn dequantize(&self, mut codes: u64, out: &mut [i32]) -> u64 {
        let bits = u32::from(self.bits);
        let mask = (1u64 << bits) - 1;
        for (slot, q) in out.iter_mut().zip(self.quant.chunks_exact(4)) {
            let (offset, step) = match *q {
                [o0, o1, s0, s1] => (i16::from_le_bytes([o0, o1]), i16::from_le_bytes([s0, s1])),
                _ => (0, 0),
            };
            *slot = i32::from(offset) + (codes & mask) as i32 * i32::from(step);
            codes >>= bits;
        }
        codes
    }

    /// The codes of `count` consecutive cells from (x, y) as the low bits of one value (cell k,
    /// channel c at bit (k · channels + c) · bits), when the cells are inside the grid and their
    /// codes span at most 57 bits (so that, wherever they start in a byte, one 64-bit read from
    /// that byte holds them).
    #[inline(always)]
    pub(crate) fn cells_window(&self, x: u32, y: u32, count: u32) -> Option<u64> {
        let cell_bits = u32::from(self.bits) * u32::from(self.channels);
        let inside =
            u64::from(x) + u64::from(count) <= u64::from(self.width()) && y < self.height();
        if count * cell_bits > 57 || !inside {
            return None;
        }
        let cell = u64::from(y) * u64::from(self.width) + u64::from(x);
        let first = cell * u64::from(cell_bits);
        let byte = (first / 8) as usize;
        // Bytes past the end of the data read as 0 (the cells' own bits are inside it).
        let bytes = match self.data.get(byte..byte + 8) {
            Some(b) => arr(b, 0),
            None => {
                let mut tail = [0u8; 8];
                for (t, &b) in tail.iter_mut().zip(self.data.get(byte..).unwrap_or(&[])) {
                    *t = b;
                }
                tail
            }
        };
        Some(u64::from_le_bytes(bytes) >> (first % 8))
    }

    /// The dequantized value `offset + code · step`; parse guarantees it fits an i16.
    pub fn value(&self, x: u32, y: u32, c: usize) -> i32 {
        let (offset, step) = self.quantization(c);
        i32::from(offset) + i32::from(self.code(x, y, c)) * i32::from(step)
    }
}

/// A grid's dequantization prepared lane by lane, for all [`MAX_GRID_CHANNELS`] lanes at once
/// (fixed-length, vector code): lane `c` of a cell whose codes start at bit `s` of a window is
/// `offset[c] + ((window >> (s + shift[c])) & mask[c]) · step[c]` — [`LatentGrid::dequantize`]'s
/// value for the grid's channels, 0 in the lanes past them (mask, offset and step 0).
#[cfg(feature = "alloc")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Dequantizer {
    offset: [i32; MAX_GRID_CHANNELS],
    step: [i32; MAX_GRID_CHANNELS],
    shift: [u32; MAX_GRID_CHANNELS],
    mask: [u64; MAX_GRID_CHANNELS],
    /// Bits of a cell's codes: where the next cell of a window starts.
    cell_bits: u32,
}

#[cfg(feature = "alloc")]
impl Dequantizer {
    pub(crate) fn new(grid: &LatentGrid<'_>) -> Dequantizer {
        let bits = grid.bits_per_latent();
        let mut d = Dequantizer {
            offset: [0; MAX_GRID_CHANNELS],
            step: [0; MAX_GRID_CHANNELS],
            shift: [0; MAX_GRID_CHANNELS],
            mask: [0; MAX_GRID_CHANNELS],
            cell_bits: bits * u32::from(grid.channels),
        };
        let lanes = d.offset.iter_mut().zip(&mut d.step).zip(&mut d.shift).zip(&mut d.mask);
        for (c, (((o, s), shift), mask)) in lanes.enumerate().take(grid.channels()) {
            let (offset, step) = grid.quantization(c);
            (*o, *s) = (i32::from(offset), i32::from(step));
            *shift = c as u32 * bits;
            *mask = (1u64 << bits) - 1;
        }
        d
    }

    /// The values of the cell whose codes start at bit `first` of `window`, into all lanes of
    /// `out`. Exact: every value `offset + code · step` is an i16 (checked at parse), so the
    /// wrapping operations never wrap; a lane past the channels shifts by whatever and masks to 0.
    #[inline(always)]
    pub(crate) fn cell(&self, window: u64, first: u32, out: &mut [i32; MAX_GRID_CHANNELS]) {
        // Lane by lane with `get`, every index below the arrays' length (so no check remains):
        // a chain of `zip`s over the five arrays is not vectorized.
        for c in 0..MAX_GRID_CHANNELS {
            let (Some(v), Some(&offset), Some(&step), Some(&shift), Some(&mask)) = (
                out.get_mut(c),
                self.offset.get(c),
                self.step.get(c),
                self.shift.get(c),
                self.mask.get(c),
            ) else {
                continue;
            };
            let code = window.wrapping_shr(first.wrapping_add(shift)) & mask;
            *v = offset.wrapping_add((code as i32).wrapping_mul(step));
        }
    }

    /// The values of two consecutive cells from one window (`LatentGrid::cells_window(…, 2)`).
    #[inline(always)]
    pub(crate) fn pair(
        &self,
        window: u64,
        (left, right): (&mut [i32; MAX_GRID_CHANNELS], &mut [i32; MAX_GRID_CHANNELS]),
    ) {
        self.cell(window, 0, left);
        self.cell(window, self.cell_bits, right);
    }
}

/// Where a texel of a `mip_w × mip_h` image falls on a grid: the 2×2 cells around it (already
/// wrapped or clamped) and the bilinear fractions in 1/256 (FORMAT.md §6.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Footprint {
    pub x0: u32,
    pub x1: u32,
    pub y0: u32,
    pub y1: u32,
    pub fx: i32,
    pub fy: i32,
}

/// One axis of the footprint: the first cell index (−1 ≤ i0 < grid_size) and the fraction in
/// 1/256. `x < mip_size` and both sizes are in 1..=16384, so the numerator is below 2^38.
pub(crate) fn axis(x: u32, mip_size: u32, grid_size: u32) -> (i64, i32) {
    let num = (2 * u64::from(x) + 1) * u64::from(grid_size) * 256;
    let den = 2 * u64::from(mip_size.max(1));
    let pos = (num / den) as i64 - 128;
    (pos >> 8, (pos & 255) as i32)
}

/// Brings index `i` into `[0, size)` by the address mode (FORMAT.md §6.1); `size` ≥ 1.
pub fn address(i: i64, size: u32, mode: AddressMode) -> u32 {
    let size = i64::from(size.max(1));
    if (0..size).contains(&i) {
        return i as u32; // the common case, without a division
    }
    match mode {
        AddressMode::Wrap => i.rem_euclid(size) as u32,
        AddressMode::Clamp => i.clamp(0, size - 1) as u32,
    }
}

/// The footprint of texel (x, y) (already addressed into the mip) on a `grid_size` grid. Public so
/// that encoders train on exactly the positions the decoder reads. Inlined, so that a kernel's
/// gather computes it in its own code (no call, no leaving its instruction set).
#[inline(always)]
pub fn footprint(
    grid_size: (u32, u32),
    x: u32,
    y: u32,
    mip_size: (u32, u32),
    mode: AddressMode,
) -> Footprint {
    let (gw, gh) = (grid_size.0.max(1), grid_size.1.max(1));
    let ((i, fx), (j, fy)) = (axis(x, mip_size.0, gw), axis(y, mip_size.1, gh));
    Footprint {
        x0: address(i, gw, mode),
        x1: address(i + 1, gw, mode),
        y0: address(j, gh, mode),
        y1: address(j + 1, gh, mode),
        fx,
        fy,
    }
}

#[cfg(all(test, feature = "alloc"))]
mod tests {
    use super::*;

    /// The prepared lanes equal `LatentGrid::dequantize` for every latent width and channel count
    /// whose cells fit a window, one cell or two, and leave 0 past the channels.
    #[test]
    fn prepared_dequantization_equals_the_grid_s() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for bits in 1..=8u8 {
            for channels in 1..=MAX_GRID_CHANNELS as u8 {
                if u32::from(bits) * u32::from(channels) > 57 {
                    continue;
                }
                let quant: [u8; 64] = core::array::from_fn(|_| (next() % 64) as u8);
                let quant = &quant[..4 * usize::from(channels)];
                let grid = LatentGrid { width: 4, height: 1, channels, bits, quant, data: &[] };
                let d = Dequantizer::new(&grid);
                for _ in 0..20 {
                    let window = next();
                    let (mut want, mut want_right) = ([0i32; 16], [0i32; 16]);
                    grid.dequantize_pair(window, (&mut want, &mut want_right));
                    let (mut got, mut got_right) = ([7i32; 16], [7i32; 16]);
                    d.cell(window, 0, &mut got);
                    assert_eq!(got, want, "{bits} bits, {channels} channels");
                    if 2 * u32::from(bits) * u32::from(channels) <= 57 {
                        d.pair(window, (&mut got, &mut got_right));
                        assert_eq!((got, got_right), (want, want_right), "pair, {bits} bits");
                    }
                }
            }
        }
    }
}
