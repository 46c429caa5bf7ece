//! `nmat-core`: the decoder of `.nmat` neural material textures.
//!
//! A material (albedo, normal, roughness, height, … up to 16 channels with their mip chain) is
//! stored as a few small quantized latent grids plus a tiny MLP; any texel of any mip can be
//! decoded on its own. This crate parses the file (validating everything once) and decodes it:
//! exactly in integer arithmetic (the same codes on every CPU kernel, the C API and the GPU
//! runtime `nmat-wgpu`) or in float as a reference. The byte layout and every step of the
//! arithmetic are specified in the repository's `docs/FORMAT.md`, embedded here as [`spec`].
//!
//! # Decoding texels
//!
//! ```
//! # fn demo(bytes: &[u8]) -> Result<(), nmat_core::Error> {
//! use nmat_core::{ChannelMask, Container};
//! let material = Container::parse(bytes)?; // validates everything once, borrows `bytes`
//! let mut codes = [0u8; 16];
//! let n = material.decode_texel_u8(10, 20, 0, ChannelMask::ALL, &mut codes)?; // integer-exact
//! let mut values = [0f32; 16];
//! material.decode_texel(10, 20, 0, ChannelMask::single(0), &mut values)?; // float reference
//! # let _ = n; Ok(()) }
//! ```
//!
//! # The fast path: [`Decoder`] (feature `alloc`)
//!
//! `Material`'s own calls follow the specification step by step. For more than a few texels,
//! prepare the network once with [`Decoder::new`]: it repacks the weights for the fastest kernel
//! of the CPU ([`Kernel::best`]: AVX-512 VNNI, AVX2 or portable code, chosen at run time) and
//! decodes whole rows at once. Results are the same bytes whichever kernel runs.
//!
//! ```
//! # fn demo(bytes: &[u8]) -> Result<(), nmat_core::Error> {
//! use nmat_core::{ChannelMask, Container, Decoder, Filter, Precision, SampleRequest};
//! let material = Container::parse(bytes)?;
//! let decoder = Decoder::new(&material); // a few KiB; keep it next to the material
//! let (width, _) = material.mip_size(0);
//! let channels = material.channel_count();
//! let mut row = vec![0u8; width as usize * channels];
//! decoder.decode_span_u8(&material, 0, 7, 0, width as usize, ChannelMask::ALL, &mut row)?;
//!
//! // Filtered lookups: nearest, bilinear, trilinear, or stochastic (one decode per sample).
//! let request = SampleRequest {
//!     u: 0.25, v: 0.75, lod: 1.5,
//!     filter: Filter::Trilinear, precision: Precision::Integer,
//!     random: [0.0; 3], channels: ChannelMask::ALL,
//! };
//! let mut values = [0f32; 16];
//! decoder.sample(&material, &request, &mut values)?; // values in each channel's range
//! # Ok(()) }
//! ```
//!
//! A small file may declare a 16384² chain: [`Material::decode_cost`] gives a mip's texels and
//! multiply-adds before any work is done.
//!
//! # What is where
//!
//! - Reading a file: [`Container::parse`] / [`Container::parse_with`] ([`ParseOptions`]) give a
//!   [`Material`]; its [`Channel`]s carry name, [`Semantic`], [`ColorSpace`] and range; every
//!   failure is an [`Error`] naming the [`Field`] or [`Argument`] at fault.
//! - Decoding: [`Material`] (per texel, [`ChannelMask`] selects channels), [`Decoder`] (prepared,
//!   rows and spans), sampling with [`SampleRequest`], [`Filter`], [`Precision`].
//! - The model: [`LatentGrid`], [`FeatureLevel`], [`Mlp`], [`Layer`], [`Requant`]; limits of this
//!   decoder in [`limits`].
//! - Writing (feature `alloc`): [`MaterialSpec`] and its parts serialize a material the decoder
//!   reads back (the encoder `nmat-encode` fills them).
//!
//! `no_std` and no allocation on any decode or parse path; `alloc` adds the writer and
//! [`Decoder`], `std` (default) run-time CPU feature detection.
#![no_std]
// Unsafe code is denied everywhere but in the decoder's kernels (`decoder/kernel/`).
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

// The public API is the items re-exported below, each at one path, and two namespaces: `bc` (BC
// layouts, encoders and decoders) and `limits` (the format's limits). What the workspace's other
// crates share with the core beyond that is in `internals`.
pub mod bc;
mod bytes;
mod decode;
#[cfg(feature = "alloc")]
mod decoder;
mod error;
mod format;
mod jpeg;
pub mod limits;
mod material;
mod neural;
mod sample;
#[cfg(feature = "alloc")]
mod writer;

/// The `.nmat` format specification (`docs/FORMAT.md` of the repository), embedded so these
/// documents stand alone.
#[cfg(doc)]
#[doc = include_str!("../../docs/FORMAT.md")]
#[allow(rustdoc::broken_intra_doc_links)] // the tables write arrays as u8[4]
pub mod spec {}

#[doc(inline)]
pub use decode::ChannelMask;
#[cfg(feature = "alloc")]
#[doc(inline)]
pub use decoder::{BcTarget, BlockRegion, Decoder, Kernel, TexelAt};
#[doc(inline)]
pub use error::{Argument, Error, Field};
#[doc(inline)]
pub use format::channel::{AddressMode, Channel, ColorSpace, Semantic};
#[doc(inline)]
pub use format::container::{
    Container, FLAG_LOD_SCALE, Header, JPEG_VERSION_MINOR, LEGACY_VERSION_MAJOR,
    LOD_SCALE_VERSION_MINOR, MAGIC, PACKED_VERSION_MINOR, ParseOptions, SectionKind, VERSION_MAJOR,
    VERSION_MINOR,
};
#[cfg(feature = "alloc")]
#[doc(inline)]
pub use format::packed::{pack, unpack};
#[doc(inline)]
pub use format::packed::{unpack_into, unpacked_len};
#[cfg(feature = "alloc")]
#[doc(inline)]
pub use jpeg::writer::{HuffmanTableSpec, JpegMaterialSpec, JpegStreamSpec};
#[doc(inline)]
pub use jpeg::{Jpeg, JpegMap};
#[doc(inline)]
pub use material::{Body, Codec, DecodeCost, FeatureLevel, Material, Mlp, Neural, Term, TermMode};
#[doc(inline)]
pub use neural::latents::LatentGrid;
#[doc(inline)]
pub use neural::mlp::{Activation, Layer, Requant};
#[doc(inline)]
pub use sample::cache::{
    CacheSize, FrameStats, MAX_CACHE_MATERIALS, MAX_CACHE_TILES, PendingTile, Slot, TILE_SIZE,
    TileCache, TileKey,
};
#[doc(inline)]
pub use sample::filter::{Filter, Precision, SampleRequest};
#[cfg(feature = "alloc")]
#[doc(inline)]
pub use writer::{ChannelSpec, GridSpec, LayerSpec, LevelSpec, MaterialSpec, MlpSpec, TermSpec};

/// What the workspace's other crates (the trainer, the GPU runtime, the tests, the fuzz targets)
/// share with the core beyond its API: the bit-exact pieces a trainer or another decoder must
/// reproduce, and the checksum tests use to forge files. Not part of the API: no stability
/// promise, hidden from the documentation.
#[doc(hidden)]
pub mod internals {
    pub use crate::decode::input_vector;
    pub use crate::format::checksum::file_checksum;
    #[cfg(feature = "alloc")]
    pub use crate::format::packed::coded_latents_len;
    pub use crate::jpeg::{HuffmanProblem, QUANT_TABLE_LEN, check_huffman_table, huffman_decoding};
    pub use crate::neural::latents::footprint;
    pub use crate::neural::mlp::hard_gelu_q;
    pub use crate::neural::posenc::triangle_q;
    #[cfg(feature = "alloc")]
    pub use crate::writer::pack_codes;
}
