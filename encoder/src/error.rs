//! Encoder errors: each names the file, map or option at fault.

use std::fmt;
use std::path::PathBuf;

#[non_exhaustive]
#[derive(Debug)]
pub enum EncodeError {
    /// A file or folder could not be read or written.
    Io { path: PathBuf, source: std::io::Error },
    /// An input path that is not a regular file (a folder, device, pipe or socket).
    NotAFile { path: PathBuf, kind: &'static str },
    /// An input file longer than the memory allowed for it (`--max-memory`).
    FileTooLarge { path: PathBuf, size: u64, limit: u64 },
    /// A file is not an image this encoder can read.
    Image { path: PathBuf, detail: String },
    /// No role could be told from a file name.
    UnknownRole { path: PathBuf },
    /// Two files claim the same role.
    DuplicateRole { role: &'static str, first: PathBuf, second: PathBuf },
    /// `--map` text that is not `role=path` with a known role.
    BadMapArgument { argument: String },
    /// No input maps.
    NoMaps { path: PathBuf },
    /// A map's size differs from the first map's (use `--resize`).
    SizeMismatch { path: PathBuf, size: (u32, u32), expected: (u32, u32), expected_from: PathBuf },
    /// A map is larger than the format allows.
    TooLarge { path: PathBuf, size: (u32, u32), limit: u32 },
    /// Loading a map would need more memory than allowed (`--max-memory`).
    OverMemory { path: PathBuf, size: (u32, u32), need: u64, max_memory: u64 },
    /// The maps add up to more channels than a material holds.
    TooManyChannels { channels: usize, limit: usize },
    /// An option value that cannot be used.
    BadOption { option: &'static str, value: String, reason: &'static str },
    /// A channel's map at a mip could not be coded as JPEG (`--codec jpeg`).
    Jpeg { channel: String, mip: u32, detail: String },
    /// The container rejected what the encoder built (a bug in the encoder).
    Format(nmat_core::Error),
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EncodeError::Io { path, source } => write!(f, "{}: {source}", path.display()),
            EncodeError::NotAFile { path, kind } => write!(
                f,
                "{}: is {kind}, not a regular file; nmat reads its inputs from regular files only",
                path.display()
            ),
            EncodeError::FileTooLarge { path, size, limit } => write!(
                f,
                "{}: {size} bytes, more than the {limit} bytes allowed; raise the limit with --max-memory",
                path.display()
            ),
            EncodeError::Image { path, detail } => {
                write!(f, "{}: not a readable image: {detail}", path.display())
            }
            EncodeError::UnknownRole { path } => write!(
                f,
                "{}: cannot tell which map this is from its name; name it like brick_albedo.png, \
                 brick_normal.png, brick_roughness.png … or pass --map role=PATH",
                path.display()
            ),
            EncodeError::DuplicateRole { role, first, second } => {
                let article = if role.starts_with(['a', 'e', 'i', 'o', 'u']) { "an" } else { "a" };
                write!(
                    f,
                    "{} and {} are both {article} {role} map; keep one or assign roles with --map",
                    first.display(),
                    second.display()
                )
            }
            EncodeError::BadMapArgument { argument } => write!(
                f,
                "--map {argument}: expected ROLE=PATH with ROLE one of {}",
                crate::texset::Role::ALL.map(|r| r.name()).join(", ")
            ),
            EncodeError::NoMaps { path } => write!(f, "{}: no image maps found", path.display()),
            EncodeError::SizeMismatch { path, size, expected, expected_from } => write!(
                f,
                "{} is {}×{} but {} is {}×{}; all maps of a material must share a size (or pass --resize)",
                path.display(),
                size.0,
                size.1,
                expected_from.display(),
                expected.0,
                expected.1
            ),
            EncodeError::TooLarge { path, size, limit } => write!(
                f,
                "{} is {}×{}; the largest side nmat stores is {limit}",
                path.display(),
                size.0,
                size.1
            ),
            EncodeError::OverMemory { path, size, need, max_memory } => write!(
                f,
                "{} declares {}×{} texels: loading it needs about {:.1} MiB, more than the {:.1} \
                 MiB allowed; raise the limit with --max-memory or use a smaller map",
                path.display(),
                size.0,
                size.1,
                *need as f64 / MIB,
                *max_memory as f64 / MIB
            ),
            EncodeError::TooManyChannels { channels, limit } => write!(
                f,
                "the maps add up to {channels} channels; a material holds at most {limit} \
                 (drop a map or its alpha)"
            ),
            EncodeError::BadOption { option, value, reason } => {
                write!(f, "{option} {value}: {reason}")
            }
            EncodeError::Jpeg { channel, mip, detail } => {
                write!(
                    f,
                    "the map of channel {channel} at mip {mip}: cannot code it as JPEG: {detail}"
                )
            }
            EncodeError::Format(e) => {
                write!(f, "internal error, the encoder built an invalid file: {e}")
            }
        }
    }
}

impl std::error::Error for EncodeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            EncodeError::Io { source, .. } => Some(source),
            EncodeError::Format(e) => Some(e),
            _ => None,
        }
    }
}

impl From<nmat_core::Error> for EncodeError {
    fn from(e: nmat_core::Error) -> Self {
        EncodeError::Format(e)
    }
}

/// Bytes in a MiB, for messages.
const MIB: f64 = (1u64 << 20) as f64;

pub(crate) fn io(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> EncodeError {
    let path = path.into();
    move |source| EncodeError::Io { path, source }
}
