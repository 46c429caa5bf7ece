//! Typed errors. Every variant names the field (or argument) at fault and carries the offending
//! value, so a user can tell a corrupt file from an unsupported one from a bad call.

use core::fmt;

/// A field of the container, as named in `docs/FORMAT.md`.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Field {
    Magic,
    VersionMajor,
    Flags,
    FileLength,
    HeaderReserved,
    Checksum,
    SectionCount,
    SectionKind,
    SectionFlags,
    SectionOffset,
    SectionLength,
    /// A section's length disagrees with what its content declares; `index` is the section kind.
    SectionContent,
    /// A required section (named by its kind in `index`) is missing.
    MissingSection,
    Width,
    Height,
    MipCount,
    ChannelCount,
    AddressMode,
    MaterialReserved,
    ChannelName,
    ChannelColorSpace,
    ChannelRange,
    ChannelReserved,
    LevelCount,
    GridCount,
    LevelsReserved,
    MipToLevel,
    GridWidth,
    GridHeight,
    GridChannels,
    GridBits,
    GridReserved,
    GridDataOffset,
    GridDataLength,
    LatentQuantization,
    TermCount,
    LevelReserved,
    TermMode,
    TermChainLength,
    TermReserved,
    TermGrid,
    /// The terms of a level produce a different number of features than the MLP takes.
    LevelFeatureWidth,
    LayerCount,
    InputFracBits,
    PeFrequencies,
    LodInput,
    InputWidth,
    MlpReserved,
    LayerInputs,
    LayerOutputs,
    LayerOutFracBits,
    LayerActivation,
    LayerReserved,
    WeightInt8,
    WeightScale,
    Bias,
    /// A version-1 file's f16 weight is not finite (FORMAT.md §10).
    FloatWeight,
    /// A version-1 file's f32 float bias is not finite (FORMAT.md §10).
    FloatBias,
    /// JPEG section (FORMAT.md §11): its version.
    JpegVersion,
    JpegMapCount,
    JpegQuantCount,
    JpegHuffmanCount,
    JpegReserved,
    /// A map record: its first channel does not follow the previous map, or the maps do not
    /// cover every channel (`index` = map count, value = channels covered).
    JpegMap,
    JpegMapChannels,
    JpegSubsampling,
    JpegQuantTable,
    JpegHuffmanTable,
    /// A Huffman table holds a symbol baseline JPEG does not define.
    JpegHuffmanSymbol,
    /// A stream record (`index` = map · mip_count + mip).
    JpegStream,
    JpegStreamOffset,
    JpegStreamLength,
    JpegTableRef,
    /// An MCU's bit offset goes backwards or past the stream's entropy data.
    JpegIndex,
    /// The file is packed (FORMAT.md §12: entropy-coded latents, or JPEG streams without their
    /// index): `Container::parse` reads fixed-rate files only; `unpack` first (value = the
    /// unpacked file's length).
    Packed,
    /// A packed section: the length of the section it stands for.
    PackedLength,
    /// A packed section: its coder's code.
    PackedCoder,
    PackedReserved,
    /// PACKED_LATENTS: the coded stream ends before the last latent, or bytes are left after it.
    PackedStream,
}

/// An argument of a decode call.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Argument {
    /// The channel mask is empty or names a channel the material does not have.
    Channels,
    /// The output slice is shorter than the number of channels asked for.
    Output,
    /// A `MaterialSpec` vector whose length contradicts the sizes it declares.
    Spec,
    /// A `Decoder` was given another material than the one it was prepared from.
    Material,
    /// A `Decoder` kernel this CPU cannot run.
    Kernel,
    /// A mip level the material does not have.
    Mip,
    /// A region of blocks past the edge of its mip.
    Region,
    /// A row pitch shorter than a row of the output.
    RowPitch,
    /// A precision the call cannot serve (a tile cache holds integer codes only).
    Precision,
    /// Memory given to a tile cache: no slot, too many, or too few texel bytes for them.
    CacheMemory,
    /// A file `pack` cannot pack without loss: a layout other than the one this crate writes
    /// (value 1), or a JPEG material whose index a scan of its streams does not rebuild
    /// (value 2).
    Layout,
}

/// Everything that can go wrong, split by cause.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// The bytes contradict the format (corrupt or hostile data). `index` says which element of a
    /// repeated structure (section, channel, grid, level, layer, row…), 0 for single fields.
    Malformed { field: Field, index: u32, value: i64 },
    /// The file is larger or denser than this decoder's named limits allow.
    LimitExceeded { field: Field, index: u32, value: u64, limit: u64 },
    /// The data needs more bytes than the file (or section) has.
    Truncated { field: Field, index: u32, needed: u64, available: u64 },
    /// A version, flag, code or mode this decoder does not know.
    Unsupported { field: Field, index: u32, value: u64 },
    /// The stored checksum does not match the bytes: the file was corrupted.
    ChecksumMismatch { stored: u32, computed: u32 },
    /// The caller passed an argument that cannot be served.
    BadArgument { argument: Argument, value: u64, limit: u64 },
    /// The allocator refused `bytes` bytes (only calls that allocate, with the `alloc` feature,
    /// e.g. `TileCache::with_capacity`).
    OutOfMemory { bytes: u64 },
}

impl fmt::Display for Field {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // The Debug names are the FORMAT.md field names in CamelCase; reuse them.
        fmt::Debug::fmt(self, f)
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::Malformed { field, index, value } => {
                write!(f, "malformed .nmat: field {field}[{index}] has invalid value {value}")
            }
            Error::LimitExceeded { field, index, value, limit } => write!(
                f,
                "limit exceeded: field {field}[{index}] is {value}, this decoder allows at most {limit}"
            ),
            Error::Truncated { field, index, needed, available } => write!(
                f,
                "truncated .nmat: {field}[{index}] needs {needed} bytes but only {available} are there"
            ),
            Error::Unsupported { field: Field::VersionMajor, value, .. } => write!(
                f,
                "unsupported .nmat: format version {value}, this decoder reads versions {} and {} \
                 (a newer nmat wrote the file: decode it with that version, or re-encode the \
                 source maps with this one)",
                crate::format::version::LEGACY_VERSION_MAJOR,
                crate::format::version::VERSION_MAJOR
            ),
            Error::Unsupported { field: Field::Packed, value, .. } => write!(
                f,
                "packed .nmat (format 2.2: entropy-coded latents, or JPEG streams without their \
                 index); unpack it first into {value} bytes (nmat_core::unpack or unpack_into; \
                 nmat and the C API do this when they open a file)"
            ),
            Error::Unsupported { field: Field::Flags, value, .. } => write!(
                f,
                "unsupported .nmat: header flags {value:#x} announce a feature this decoder lacks \
                 (a newer nmat wrote the file: decode it with that version, or re-encode the \
                 source maps with this one)"
            ),
            Error::Unsupported { field, index, value } => {
                write!(f, "unsupported .nmat: field {field}[{index}] has unknown value {value}")
            }
            Error::ChecksumMismatch { stored, computed } => write!(
                f,
                "corrupt .nmat: checksum is {stored:#010x} but the bytes give {computed:#010x}"
            ),
            Error::BadArgument { argument, value, limit } => {
                write!(f, "bad argument {argument:?}: value {value}, limit {limit}")
            }
            Error::OutOfMemory { bytes } => {
                write!(f, "out of memory: {bytes} bytes could not be allocated")
            }
        }
    }
}

impl core::error::Error for Error {}

pub(crate) fn malformed(field: Field, index: usize, value: impl TryInto<i64>) -> Error {
    Error::Malformed { field, index: index as u32, value: value.try_into().unwrap_or(i64::MAX) }
}

pub(crate) fn unsupported(field: Field, index: usize, value: impl Into<u64>) -> Error {
    Error::Unsupported { field, index: index as u32, value: value.into() }
}

/// Checks `value <= limit`, naming the field otherwise.
pub(crate) fn at_most(field: Field, index: usize, value: u64, limit: u64) -> Result<(), Error> {
    if value > limit {
        return Err(Error::LimitExceeded { field, index: index as u32, value, limit });
    }
    Ok(())
}
