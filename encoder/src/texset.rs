//! A texture set: the maps of one material, their roles, how their channels are packed, and the
//! mip chain every channel is trained on (values in unit scale, [0, 1]).

use crate::error::{EncodeError, io};
use image::{DynamicImage, ImageBuffer, Luma};
use nmat_core::limits::{MAX_CHANNELS, MAX_DIMENSION};
use std::path::{Path, PathBuf};

pub use crate::role::Role;

/// Role from a file name, by the naming conventions of common tools: a token of the stem
/// (split at `_ - . space`) such as `albedo`, `diffuse`, `basecolor`, `normal`, `n`, `nm`, `rough`,
/// `gloss`, `spec`, `s`, `height`, `z`, `bump`, `disp`, `ao`, `metallic`, `emissive`, `glow`,
/// `opacity`. The last matching token wins (`rock_normal_ao` is an AO map).
pub fn role_from_name(path: &Path) -> Option<Role> {
    let stem = path.file_stem()?.to_string_lossy().to_ascii_lowercase();
    let tokens: Vec<&str> = stem.split(|c: char| !c.is_ascii_alphanumeric()).collect();
    tokens.iter().rev().find_map(|t| match *t {
        "albedo" | "diffuse" | "diff" | "base" | "basecolor" | "basecolour" | "color"
        | "colour" | "col" | "d" => Some(Role::Albedo),
        "normal" | "normals" | "n" | "nm" | "norm" | "nrm" | "normalmap" => Some(Role::Normal),
        "roughness" | "rough" | "r" => Some(Role::Roughness),
        "gloss" | "glossiness" | "g" => Some(Role::Gloss),
        "spec" | "specular" | "s" => Some(Role::Specular),
        "height" | "z" | "bump" | "disp" | "displacement" | "h" => Some(Role::Height),
        "ao" | "occlusion" | "ambientocclusion" => Some(Role::Ao),
        "metallic" | "metal" | "metalness" | "m" => Some(Role::Metallic),
        "emissive" | "emission" | "glow" | "e" => Some(Role::Emissive),
        "opacity" | "alpha" | "transparency" => Some(Role::Opacity),
        _ => None,
    })
}

/// How a source file's pixels were laid out, to write them back the same way.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileLayout {
    Gray = 1,
    GrayAlpha = 2,
    Rgb = 3,
    Rgba = 4,
}

impl FileLayout {
    pub fn from_code(c: u8) -> Option<FileLayout> {
        [FileLayout::Gray, FileLayout::GrayAlpha, FileLayout::Rgb, FileLayout::Rgba]
            .into_iter()
            .find(|l| *l as u8 == c)
    }
    pub fn components(self) -> usize {
        self as usize
    }
}

/// One source map and where its components went.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceMap {
    pub role: Role,
    /// File name without folder, as written back by `decode`.
    pub file_name: String,
    pub layout: FileLayout,
    /// Material channel of each file component (`None`: not stored, see `alpha_value`/`gray_rgb`).
    pub first_channel: usize,
    /// Channels this map occupies in the material (1–4).
    pub channel_count: usize,
    /// The file was RGB(A) with R = G = B: one channel is stored and replicated on output.
    pub gray_rgb: bool,
    /// The file had a constant alpha, not stored; its 8-bit value.
    pub alpha_value: Option<u8>,
    /// The file had 16 bits per component.
    pub sixteen_bit: bool,
}

/// One output channel of the material.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelInfo {
    pub name: String,
    pub role: Role,
    pub component: u8,
    /// `Some(unit value)` when the channel is the same everywhere: stored as a constant, not
    /// learned by the network.
    pub constant: Option<f32>,
}

/// One level of the mip chain: `width × height × channels` unit values, channel fastest.
#[derive(Clone, Debug, PartialEq)]
pub struct MipImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct TextureSet {
    pub width: u32,
    pub height: u32,
    pub channels: Vec<ChannelInfo>,
    pub maps: Vec<SourceMap>,
    pub mips: Vec<MipImage>,
}

impl TextureSet {
    pub fn channel_count(&self) -> usize {
        self.channels.len()
    }
    /// Channels the network learns (not constant).
    pub fn learned_channels(&self) -> Vec<usize> {
        (0..self.channels.len()).filter(|&c| self.channels[c].constant.is_none()).collect()
    }
}

/// Input to [`load`]: files with roles (detected or given).
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Resize every map to the size of the first (in role order) with Lanczos3 instead of failing.
    pub resize: bool,
    /// Memory, in bytes, that loading may use: a map whose declared size would need more (at
    /// [`LOAD_BYTES_PER_TEXEL`]) is refused before its pixels are decoded, and the image decoder
    /// allocates no more than this.
    pub max_memory: u64,
}

/// Default [`LoadOptions::max_memory`]: 8 GiB, a 8192² material with room to spare on a typical
/// 16 GiB machine.
pub const DEFAULT_MAX_MEMORY: u64 = 8 << 30;

/// Bytes per texel loading one map may hold at once: the decoded image (≤ 16, RGBA f32), its
/// RGBA f32 copy (16) and the planes (≤ 16).
pub const LOAD_BYTES_PER_TEXEL: u64 = 48;

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { resize: false, max_memory: DEFAULT_MAX_MEMORY }
    }
}

const IMAGE_EXTENSIONS: [&str; 8] = ["png", "tga", "jpg", "jpeg", "bmp", "tif", "tiff", "webp"];

/// Expands folders into their image files (sorted by name), keeps files as given.
pub fn collect_inputs(paths: &[PathBuf]) -> Result<Vec<PathBuf>, EncodeError> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(io(p))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| {
                    f.extension().is_some_and(|e| {
                        IMAGE_EXTENSIONS
                            .contains(&e.to_string_lossy().to_ascii_lowercase().as_str())
                    })
                })
                .collect();
            if found.is_empty() {
                return Err(EncodeError::NoMaps { path: p.clone() });
            }
            found.sort();
            files.extend(found);
        } else if p.symlink_metadata().is_err() {
            return Err(EncodeError::Io {
                path: p.clone(),
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or folder"),
            });
        } else {
            files.push(p.clone());
        }
    }
    Ok(files)
}

/// Parses `role=path`.
pub fn parse_map_argument(arg: &str) -> Result<(Role, PathBuf), EncodeError> {
    let bad = || EncodeError::BadMapArgument { argument: arg.to_string() };
    let (role, path) = arg.split_once('=').ok_or_else(bad)?;
    let role = Role::parse(role.trim()).ok_or_else(bad)?;
    if path.is_empty() {
        return Err(bad());
    }
    Ok((role, PathBuf::from(path)))
}

/// Assigns roles: explicit ones first, then detected from names. Errors name the file.
pub fn assign_roles(
    files: &[PathBuf],
    explicit: &[(Role, PathBuf)],
) -> Result<Vec<(Role, PathBuf)>, EncodeError> {
    let mut out: Vec<(Role, PathBuf)> = Vec::new();
    let mut push = |role: Role, path: PathBuf| {
        if let Some((_, first)) = out.iter().find(|(r, _)| *r == role) {
            return Err(EncodeError::DuplicateRole {
                role: role.name(),
                first: first.clone(),
                second: path,
            });
        }
        out.push((role, path));
        Ok(())
    };
    for (role, path) in explicit {
        push(*role, path.clone())?;
    }
    for f in files {
        if explicit.iter().any(|(_, p)| p == f) {
            continue;
        }
        let role = role_from_name(f).ok_or_else(|| EncodeError::UnknownRole { path: f.clone() })?;
        push(role, f.clone())?;
    }
    if out.is_empty() {
        return Err(EncodeError::NoMaps { path: PathBuf::from(".") });
    }
    out.sort_by_key(|(r, _)| *r);
    Ok(out)
}

fn open_image(path: &Path, max_memory: u64) -> Result<DynamicImage, EncodeError> {
    // Opened once (a folder, device or FIFO is refused by name); read twice from the start.
    let (file, _) = crate::input::open_regular(path)?;
    let open = || {
        use std::io::Seek as _;
        let mut f = file.try_clone()?;
        f.rewind()?;
        Ok(std::io::BufReader::new(f))
    };
    decode_image_with(open, path, max_memory)
}

/// Decodes an image file's bytes exactly as `load` decodes a map (`path` only names it in
/// errors): the declared size checked against [`MAX_DIMENSION`] and `max_memory` before any pixel
/// is decoded, and the decoder's allocations limited to `max_memory`.
pub fn decode_image(
    bytes: &[u8],
    path: &Path,
    max_memory: u64,
) -> Result<DynamicImage, EncodeError> {
    decode_image_with(|| Ok(std::io::Cursor::new(bytes)), path, max_memory)
}

/// The one image decoding: `open` gives the file's bytes from the start (it is called twice: once
/// for the header, once for the pixels).
fn decode_image_with<R: std::io::BufRead + std::io::Seek>(
    open: impl Fn() -> std::io::Result<R>,
    path: &Path,
    max_memory: u64,
) -> Result<DynamicImage, EncodeError> {
    let image_err = |detail: String| EncodeError::Image { path: path.to_path_buf(), detail };
    // The format from the file's extension (TGA has no signature), overridden by the content's
    // signature where it has one — as `ImageReader::open` does.
    let reader = || -> Result<image::ImageReader<R>, EncodeError> {
        let mut reader = image::ImageReader::new(open().map_err(io(path))?);
        if let Ok(format) = image::ImageFormat::from_path(path) {
            reader.set_format(format);
        }
        reader.with_guessed_format().map_err(io(path))
    };
    // The declared size is checked before any pixel is allocated.
    let (w, h) = reader()?.into_dimensions().map_err(|e| image_err(e.to_string()))?;
    if w > MAX_DIMENSION || h > MAX_DIMENSION {
        return Err(EncodeError::TooLarge {
            path: path.to_path_buf(),
            size: (w, h),
            limit: MAX_DIMENSION,
        });
    }
    if w == 0 || h == 0 {
        return Err(image_err("the image is empty".into()));
    }
    let need = u64::from(w) * u64::from(h) * LOAD_BYTES_PER_TEXEL;
    if need > max_memory {
        return Err(EncodeError::OverMemory {
            path: path.to_path_buf(),
            size: (w, h),
            need,
            max_memory,
        });
    }
    let mut reader = reader()?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_memory);
    reader.limits(limits);
    reader.decode().map_err(|e| image_err(e.to_string()))
}

/// Unit-scale components of an image: `(layout, 16-bit, planes)`, one plane per component.
/// Palette images arrive expanded to RGB(A) by the decoder; float images are clamped to [0, 1];
/// CMYK JPEGs arrive converted to RGB. All are documented conversions (docs/ENCODING.md).
fn planes(img: &DynamicImage) -> (FileLayout, bool, Vec<Vec<f32>>) {
    use image::ColorType as C;
    let color = img.color();
    let sixteen = matches!(color, C::L16 | C::La16 | C::Rgb16 | C::Rgba16);
    let layout = match (color.has_color(), color.has_alpha()) {
        (false, false) => FileLayout::Gray,
        (false, true) => FileLayout::GrayAlpha,
        (true, false) => FileLayout::Rgb,
        (true, true) => FileLayout::Rgba,
    };
    let n = layout.components();
    let rgba = img.to_rgba32f();
    let picks: &[usize] = match layout {
        FileLayout::Gray => &[0],
        FileLayout::GrayAlpha => &[0, 3],
        FileLayout::Rgb => &[0, 1, 2],
        FileLayout::Rgba => &[0, 1, 2, 3],
    };
    let mut out = vec![Vec::with_capacity((img.width() * img.height()) as usize); n];
    // Integer sources are re-snapped to code / full-scale exactly, whatever rounding the image
    // decoder's float conversion used.
    let full = if sixteen { 65535.0 } else { 255.0 };
    let is_float = matches!(color, C::Rgb32F | C::Rgba32F);
    for p in rgba.pixels() {
        for (plane, &k) in out.iter_mut().zip(picks) {
            let v = p.0[k].clamp(0.0, 1.0);
            plane.push(if is_float { v } else { (v * full).round() / full });
        }
    }
    (layout, sixteen, out)
}

fn resize_plane(plane: &[f32], from: (u32, u32), to: (u32, u32)) -> Vec<f32> {
    let img: ImageBuffer<Luma<f32>, Vec<f32>> =
        ImageBuffer::from_raw(from.0, from.1, plane.to_vec()).unwrap_or_default();
    let out = image::imageops::resize(&img, to.0, to.1, image::imageops::FilterType::Lanczos3);
    // Lanczos rings past the input range; the stored values are unit scale.
    out.into_raw().into_iter().map(|v| v.clamp(0.0, 1.0)).collect()
}

/// The 8-bit code of a constant alpha, kept out of the channels (SOURCE_MAPS stores it as one
/// byte); `None` when a byte cannot hold it exactly (a 16-bit alpha between two 8-bit codes), so
/// the alpha stays a (constant) channel and comes back exactly.
fn constant_alpha_code(unit: f32) -> Option<u8> {
    let code = (unit * 255.0).round();
    (code / 255.0 == unit).then_some(code as u8)
}

fn is_constant(plane: &[f32]) -> Option<f32> {
    let first = *plane.first()?;
    plane.iter().all(|&v| v == first).then_some(first)
}

/// Loads the maps, packs their channels and builds the mip chain (each mip from the previous one
/// with Lanczos3, sizes `max(1, size >> m)`, values clamped to [0, 1]).
pub fn load(maps: &[(Role, PathBuf)], options: &LoadOptions) -> Result<TextureSet, EncodeError> {
    let mut size: Option<((u32, u32), PathBuf)> = None;
    let mut channels = Vec::new();
    let mut sources = Vec::new();
    let mut mip0_planes: Vec<Vec<f32>> = Vec::new();
    for (role, path) in maps {
        let img = open_image(path, options.max_memory)?;
        let (w, h) = (img.width(), img.height());
        let (layout, sixteen_bit, mut planes) = planes(&img);
        let (expected, from) = size.get_or_insert(((w, h), path.clone())).clone();
        if (w, h) != expected {
            if !options.resize {
                return Err(EncodeError::SizeMismatch {
                    path: path.clone(),
                    size: (w, h),
                    expected,
                    expected_from: from,
                });
            }
            planes = planes.iter().map(|p| resize_plane(p, (w, h), expected)).collect();
        }
        let has_alpha = matches!(layout, FileLayout::GrayAlpha | FileLayout::Rgba);
        let alpha_value = if has_alpha {
            planes.last().and_then(|a| is_constant(a)).and_then(constant_alpha_code)
        } else {
            None
        };
        if alpha_value.is_some() {
            planes.pop();
        }
        // Channels by content, whatever the role: a colour map whose planes are identical on every
        // texel is one channel, replicated on the way back. Only exact equality counts: a map
        // that is gray only approximately stays RGB (no lossy guess).
        let gray_rgb = planes.len() >= 3 && planes[0] == planes[1] && planes[1] == planes[2];
        if gray_rgb {
            planes.drain(1..3);
        }
        let first_channel = channels.len();
        for (k, plane) in planes.iter().enumerate() {
            let is_alpha = has_alpha && alpha_value.is_none() && k + 1 == planes.len();
            let suffix = if is_alpha {
                ".a".to_string()
            } else if planes.len() == 1 || (gray_rgb && k == 0 && planes.len() == 2) {
                String::new()
            } else if *role == Role::Normal {
                [".x", ".y", ".z"][k.min(2)].to_string()
            } else {
                [".r", ".g", ".b"][k.min(2)].to_string()
            };
            channels.push(ChannelInfo {
                name: format!("{}{suffix}", role.name()),
                role: *role,
                component: if is_alpha { 3 } else { k as u8 },
                constant: is_constant(plane),
            });
        }
        sources.push(SourceMap {
            role: *role,
            file_name: path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            layout,
            first_channel,
            channel_count: planes.len(),
            gray_rgb,
            alpha_value,
            sixteen_bit,
        });
        mip0_planes.extend(planes);
    }
    if channels.len() > MAX_CHANNELS {
        return Err(EncodeError::TooManyChannels { channels: channels.len(), limit: MAX_CHANNELS });
    }
    let ((width, height), _) = size.ok_or(EncodeError::NoMaps { path: PathBuf::from(".") })?;
    let mips = build_mips(width, height, mip0_planes);
    Ok(TextureSet { width, height, channels, maps: sources, mips })
}

/// The full mip chain from channel planes of mip 0.
pub fn build_mips(width: u32, height: u32, planes: Vec<Vec<f32>>) -> Vec<MipImage> {
    let count = 32 - width.max(height).leading_zeros();
    let mut mips = Vec::new();
    let mut level = planes;
    let (mut w, mut h) = (width, height);
    for m in 0..count {
        if m > 0 {
            let (nw, nh) = ((width >> m).max(1), (height >> m).max(1));
            level = level.iter().map(|p| resize_plane(p, (w, h), (nw, nh))).collect();
            (w, h) = (nw, nh);
        }
        mips.push(interleave(w, h, &level));
    }
    mips
}

fn interleave(w: u32, h: u32, planes: &[Vec<f32>]) -> MipImage {
    let n = (w * h) as usize;
    let mut data = Vec::with_capacity(n * planes.len());
    for i in 0..n {
        data.extend(planes.iter().map(|p| p[i]));
    }
    MipImage { width: w, height: h, data }
}
