//! The file's identity: its magic and the versions this crate writes and reads (FORMAT.md §1.3).

/// First four bytes of every file.
pub const MAGIC: [u8; 4] = *b"NMAT";
/// Major version written by this crate. A reader reads this major and [`LEGACY_VERSION_MAJOR`]
/// and rejects any other (FORMAT.md §1.3).
pub const VERSION_MAJOR: u16 = 2;
/// The previous major version, still read: its layer blocks carry a second, f16 copy of the
/// network, which is validated and skipped (FORMAT.md §10).
pub const LEGACY_VERSION_MAJOR: u16 = 1;
/// Minor version written by this crate for neural materials; a reader accepts every minor of its
/// major (§1.3).
pub const VERSION_MINOR: u16 = 0;
/// Minor version of files with a JPEG section (2.1 added it, §11).
pub const JPEG_VERSION_MINOR: u16 = 1;
/// Minor version of files whose latents are entropy-coded (2.2 added PACKED_LATENTS, §12).
pub const PACKED_VERSION_MINOR: u16 = 2;
/// Minor version of files whose LOD feature is scaled other than `mip / 16` (2.3 added it:
/// header flag [`FLAG_LOD_SCALE`], §6.5).
pub const LOD_SCALE_VERSION_MINOR: u16 = 3;
/// Header flag: the MLP's `lod_input` may be 2–5, a LOD feature of `mip · 2^(lod_input − 5)`
/// (§5.3, §6.5). Readers before 2.3 refuse such a file (`Unsupported Flags`) instead of decoding it
/// with the wrong feature.
pub const FLAG_LOD_SCALE: u32 = 1;
/// Every header flag this crate knows.
pub const KNOWN_FLAGS: u32 = FLAG_LOD_SCALE;
