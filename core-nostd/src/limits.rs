//! Named limits (docs/FORMAT.md §7). Each one bounds memory, work or integer range; the reason is
//! next to it. A file beyond a limit is rejected with `Error::LimitExceeded`.

/// Largest texture side. 16384 is the largest mandatory 2D texture size of current desktop APIs,
/// and it keeps `(2x+1)·grid_size·256` (the sampling position numerator) below 2^38.
pub const MAX_DIMENSION: u32 = 16384;
/// floor(log2(MAX_DIMENSION)) + 1.
pub const MAX_MIPS: usize = 15;
/// Channels of a material; the channel mask is a `u16`.
pub const MAX_CHANNELS: usize = 16;
/// Sections in the table. Four are defined; the rest leaves room for optional extensions.
pub const MAX_SECTIONS: usize = 16;
/// Feature levels (NTC uses up to 7 for a 16k texture, NBC 4).
pub const MAX_LEVELS: usize = 8;
/// Latent grids across all levels (two per level in the NTC layout).
pub const MAX_GRIDS: usize = 16;
/// Largest grid side.
pub const MAX_GRID_DIMENSION: u32 = 16384;
/// Latent channels of one grid.
pub const MAX_GRID_CHANNELS: usize = 16;
/// Sampling terms per level (NTC needs 2).
pub const MAX_TERMS: usize = 4;
/// Grids summed by one residual-fusion chain (one per level at most).
pub const MAX_CHAIN: usize = MAX_LEVELS;
/// MLP layers (NTC: 2 hidden + 1 output).
pub const MAX_LAYERS: usize = 4;
/// Fan-in and width of every layer. The accumulator bound of docs/FORMAT.md §5.3
/// (|acc| ≤ 128·127·32768 + |bias| < 2^31) holds up to this fan-in; larger needs a new bound.
pub const MAX_WIDTH: usize = 128;
/// Triangle-wave frequencies of the positional encoding (periods 4 … 512 texels).
pub const MAX_PE_FREQUENCIES: u8 = 8;
/// Activation fraction bits: hardGELU's `z·(z + 1.5·2^f)` fits an i32 only for f ≤ 14.
pub const MAX_FRAC_BITS: u8 = 14;
/// The LOD feature (at least `mip / 16`, FORMAT.md §6.5) must be exact in the input format, hence
/// f ≥ 4.
pub const MIN_INPUT_FRAC_BITS: u8 = 4;
/// Bits per latent.
pub const MAX_LATENT_BITS: u8 = 8;
