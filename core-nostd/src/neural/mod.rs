//! The neural codec: bit-packed latent grids and their sampling footprints, the positional
//! encoding, and the network in exact integer and in float arithmetic (FORMAT.md §4–§6).

pub(crate) mod latents;
pub(crate) mod mlp;
pub(crate) mod posenc;
