//! Encoder errors: each names the file, map or option at fault. Options are named as this API
//! has them (`LoadOptions::max_memory`, …); a front end names them its own way through
//! [`EncodeError::naming_options`] (the `nmat` command by its flags).

use std::fmt;
use std::path::PathBuf;

#[non_exhaustive]
#[derive(Debug)]
pub enum EncodeError {
    /// A file or folder could not be read or written.
    Io { path: PathBuf, source: std::io::Error },
    /// An input path that is not a regular file (a folder, device, pipe or socket).
    NotAFile { path: PathBuf, kind: &'static str },
    /// An input file longer than the memory allowed for it ([`EncodeOption::MaxMemory`]).
    FileTooLarge { path: PathBuf, size: u64, limit: u64 },
    /// A file is not an image this encoder can read.
    Image { path: PathBuf, detail: String },
    /// No role could be told from a file name.
    UnknownRole { path: PathBuf },
    /// Two files claim the same role.
    DuplicateRole { role: &'static str, first: PathBuf, second: PathBuf },
    /// An explicit role assignment ([`EncodeOption::Map`]) that is not `role=path` with a known
    /// role.
    BadMapArgument { argument: String },
    /// No input maps.
    NoMaps { path: PathBuf },
    /// A map's size differs from the first map's (see [`EncodeOption::Resize`]).
    SizeMismatch { path: PathBuf, size: (u32, u32), expected: (u32, u32), expected_from: PathBuf },
    /// A map is larger than the format allows.
    TooLarge { path: PathBuf, size: (u32, u32), limit: u32 },
    /// Loading a map would need more memory than allowed ([`EncodeOption::MaxMemory`]).
    OverMemory { path: PathBuf, size: (u32, u32), need: u64, max_memory: u64 },
    /// The maps add up to more channels than a material holds.
    TooManyChannels { channels: usize, limit: usize },
    /// An option value that cannot be used.
    BadOption { option: EncodeOption, value: String, reason: &'static str },
    /// A channel's map at a mip could not be coded as JPEG (`jpeg::encode_jpeg`).
    Jpeg { channel: String, mip: u32, detail: String },
    /// The container rejected what the encoder built (a bug in the encoder).
    Format(nmat_core::Error),
}

/// An option of the encoder that an error names, so that a front end can name it its own way
/// ([`EncodeError::naming_options`]).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EncodeOption {
    /// The memory a load may use: `LoadOptions::max_memory`, the limit of `input::read_regular`.
    MaxMemory,
    /// Resizing maps to the first map's size: `LoadOptions::resize`.
    Resize,
    /// A role assigned explicitly, `ROLE=PATH` (`texset::parse_map_argument`).
    Map,
    /// The JPEG quality: `jpeg::JpegOptions::quality`.
    Quality,
    /// The rate of `jpeg::encode_jpeg_to_rate`, in bits per pixel per channel.
    Bppc,
    /// The optimizer steps: `TrainOptions::steps`.
    Steps,
    /// The whole-chain PSNR a search for the smallest profile aims at, in dB.
    TargetPsnr,
    /// How much larger than the nominal rate a packed file's in-memory layout may be:
    /// `EncodeOptions::memory_factor`.
    MemoryFactor,
    /// How far past their range outputs may go without cost: `TrainOptions::output_margin`.
    OutputMargin,
}

impl EncodeOption {
    /// The option as this API names it.
    pub fn api_name(self) -> &'static str {
        match self {
            EncodeOption::MaxMemory => "LoadOptions::max_memory",
            EncodeOption::Resize => "LoadOptions::resize",
            EncodeOption::Map => "explicit role",
            EncodeOption::Quality => "JpegOptions::quality",
            EncodeOption::Bppc => "bppc",
            EncodeOption::Steps => "TrainOptions::steps",
            EncodeOption::TargetPsnr => "target PSNR",
            EncodeOption::MemoryFactor => "EncodeOptions::memory_factor",
            EncodeOption::OutputMargin => "TrainOptions::output_margin",
        }
    }
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write(f, EncodeOption::api_name)
    }
}

/// An [`EncodeError`] shown with its options named by a front end ([`EncodeError::naming_options`]).
pub struct Named<'a> {
    error: &'a EncodeError,
    name: fn(EncodeOption) -> &'static str,
}

impl fmt::Display for Named<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.error.write(f, self.name)
    }
}

impl EncodeError {
    /// The message with every option named by `name` (for example a command's flags:
    /// `EncodeOption::MaxMemory` → `--max-memory`); `Display` names them as this API does.
    pub fn naming_options(&self, name: fn(EncodeOption) -> &'static str) -> Named<'_> {
        Named { error: self, name }
    }

    fn write(
        &self,
        f: &mut fmt::Formatter<'_>,
        name: fn(EncodeOption) -> &'static str,
    ) -> fmt::Result {
        use EncodeOption as O;
        match self {
            EncodeError::Io { path, source } => write!(f, "{}: {source}", path.display()),
            EncodeError::NotAFile { path, kind } => write!(
                f,
                "{}: is {kind}, not a regular file; nmat reads its inputs from regular files only",
                path.display()
            ),
            EncodeError::FileTooLarge { path, size, limit } => write!(
                f,
                "{}: {size} bytes, more than the {limit} bytes allowed; raise the limit with {}",
                path.display(),
                name(O::MaxMemory)
            ),
            EncodeError::Image { path, detail } => {
                write!(f, "{}: not a readable image: {detail}", path.display())
            }
            EncodeError::UnknownRole { path } => write!(
                f,
                "{}: cannot tell which map this is from its name; name it like brick_albedo.png, \
                 brick_normal.png, brick_roughness.png … or assign its role with {} ROLE=PATH",
                path.display(),
                name(O::Map)
            ),
            EncodeError::DuplicateRole { role, first, second } => {
                let article = if role.starts_with(['a', 'e', 'i', 'o', 'u']) { "an" } else { "a" };
                write!(
                    f,
                    "{} and {} are both {article} {role} map; keep one or assign roles with {}",
                    first.display(),
                    second.display(),
                    name(O::Map)
                )
            }
            EncodeError::BadMapArgument { argument } => write!(
                f,
                "{} {argument}: expected ROLE=PATH with ROLE one of {}",
                name(O::Map),
                crate::role::Role::ALL.map(|r| r.name()).join(", ")
            ),
            EncodeError::NoMaps { path } => write!(f, "{}: no image maps found", path.display()),
            EncodeError::SizeMismatch { path, size, expected, expected_from } => write!(
                f,
                "{} is {}×{} but {} is {}×{}; all maps of a material must share a size (or pass {})",
                path.display(),
                size.0,
                size.1,
                expected_from.display(),
                expected.0,
                expected.1,
                name(O::Resize)
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
                 MiB allowed; raise the limit with {} or use a smaller map",
                path.display(),
                size.0,
                size.1,
                *need as f64 / MIB,
                *max_memory as f64 / MIB,
                name(O::MaxMemory)
            ),
            EncodeError::TooManyChannels { channels, limit } => write!(
                f,
                "the maps add up to {channels} channels; a material holds at most {limit} \
                 (drop a map or its alpha)"
            ),
            EncodeError::BadOption { option, value, reason } => {
                write!(f, "{} {value}: {reason}", name(*option))
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

#[cfg(test)]
mod tests {
    use super::*;
    use EncodeOption as O;

    /// One error of each kind that names an option.
    fn naming_options() -> Vec<EncodeError> {
        let p = || PathBuf::from("a_albedo.png");
        vec![
            EncodeError::FileTooLarge { path: p(), size: 10, limit: 5 },
            EncodeError::UnknownRole { path: p() },
            EncodeError::DuplicateRole { role: "albedo", first: p(), second: p() },
            EncodeError::BadMapArgument { argument: "colour=x.png".into() },
            EncodeError::SizeMismatch {
                path: p(),
                size: (8, 8),
                expected: (4, 4),
                expected_from: p(),
            },
            EncodeError::OverMemory {
                path: p(),
                size: (64, 64),
                need: 1 << 20,
                max_memory: 1 << 10,
            },
            EncodeError::BadOption {
                option: EncodeOption::Quality,
                value: "0".into(),
                reason: "must be between 1 and 100",
            },
        ]
    }

    #[test]
    fn options_are_named_as_the_api_has_them_or_as_a_front_end_names_them() {
        let flag = |o: EncodeOption| match o {
            EncodeOption::MaxMemory => "--max-memory",
            EncodeOption::Resize => "--resize",
            EncodeOption::Map => "--map",
            EncodeOption::Quality => "--quality",
            _ => "--other",
        };
        for e in naming_options() {
            let (api, shown) = (e.to_string(), e.naming_options(flag).to_string());
            assert!(!api.contains("--"), "the API's message names a flag: {api}");
            assert!(shown.contains("--"), "the front end's names are not used: {shown}");
            let back = ["--max-memory", "--resize", "--map", "--quality"]
                .into_iter()
                .zip([O::MaxMemory, O::Resize, O::Map, O::Quality])
                .fold(shown.clone(), |s, (f, o)| s.replace(f, o.api_name()));
            assert_eq!(back, api, "only the option names differ");
        }
        let over = &naming_options()[5];
        assert!(
            over.naming_options(flag).to_string().contains("raise the limit with --max-memory")
        );
        assert!(over.to_string().contains("raise the limit with LoadOptions::max_memory"));
    }
}
