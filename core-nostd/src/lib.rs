//! `nmat-core`: the decoder of `.nmat` neural material textures.
//!
//! A material (albedo, normal, roughness, height, … up to 16 channels with their mip chain) is
//! stored as a few small quantized latent grids plus a tiny MLP; any texel of any mip can be
//! decoded on its own. The byte layout and the decode arithmetic are specified in
//! `docs/FORMAT.md`; this crate is its reference implementation.
//!
//! ```
//! # fn demo(bytes: &[u8]) -> Result<(), nmat_core::Error> {
//! use nmat_core::{ChannelMask, Container};
//! let material = Container::parse(bytes)?; // validates everything once, borrows `bytes`
//! let mut rgb = [0u8; 16];
//! let n = material.decode_texel_u8(10, 20, 0, ChannelMask::ALL, &mut rgb)?; // integer-exact
//! let mut values = [0f32; 16];
//! material.decode_texel(10, 20, 0, ChannelMask::single(0), &mut values)?; // float reference
//! # let _ = n; Ok(()) }
//! ```
//!
//! `no_std`, no allocation on any decode or parse path; the writer needs the `alloc` feature.
#![no_std]
// Unsafe code is denied everywhere but in the two SIMD modules (`batch/avx2.rs`, `batch/avx512.rs`).
#![deny(unsafe_code)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::std_instead_of_core,
        clippy::alloc_instead_of_core
    )
)]

#[cfg(feature = "alloc")]
pub mod batch;
mod bytes;
pub mod checksum;
pub mod container;
pub mod decode;
pub mod error;
pub mod filter;
pub mod latents;
pub mod limits;
pub mod material;
pub mod mlp;
pub mod posenc;
#[cfg(feature = "alloc")]
pub mod writer;

#[cfg(feature = "alloc")]
pub use batch::{Decoder, Kernel};
pub use container::{
    Container, Header, LEGACY_VERSION_MAJOR, ParseOptions, SectionKind, VERSION_MAJOR,
};
pub use decode::ChannelMask;
pub use error::{Argument, Error, Field};
pub use filter::{Filter, Precision, SampleRequest};
pub use latents::LatentGrid;
pub use material::{
    AddressMode, Channel, ColorSpace, DecodeCost, FeatureLevel, Material, Mlp, Semantic, Term,
    TermMode,
};
pub use mlp::{Activation, Layer, Requant};
#[cfg(feature = "alloc")]
pub use writer::{ChannelSpec, GridSpec, LayerSpec, LevelSpec, MaterialSpec, MlpSpec, TermSpec};
