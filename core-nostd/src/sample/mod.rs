//! Sampling a material as a texture unit does — nearest, bilinear, trilinear and stochastic
//! filters over its mips — and the tile cache that decodes each texel a frame touches once.

pub(crate) mod cache;
pub(crate) mod filter;
