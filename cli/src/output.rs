//! What the CLI prints and writes: descriptions, quality tables, decoded maps, atomic files.

use image::ImageFormat;
use nmat_core::{Body, ChannelMask, DecodeCost, Decoder, Material, SectionKind};
use nmat_encode::ByteBudget;
use nmat_encode::metrics::{ChainQuality, unit_of};
use nmat_encode::source_maps;
use nmat_encode::texset::TextureSet;
use nmat_encode::texset::{FileLayout, Role, SourceMap};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use crate::input::Stored;

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so a reader
/// never sees a partial file and a failure leaves no output behind. The temporary file has an
/// unpredictable name and is created exclusively: a file or symlink planted under a name nmat
/// might pick is never opened, so it cannot redirect the write.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let context =
        |e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: {e}", path.display()));
    let (tmp, mut f) = create_exclusive(dir, &name).map_err(context)?;
    let result = (|| {
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(context)
}

/// Checks, before any long work, that [`write_atomic`] can write `path` (given as `-o`): it is
/// not a directory, it is none of `inputs` (a source is never replaced), and its folder exists
/// and accepts a new file.
pub fn check_output(path: &Path, inputs: &[PathBuf]) -> Result<(), String> {
    check_output_file("-o", path, inputs)
}

/// [`check_output`] for the output file given as `option` (`-o`, `--csv`, `--image`, …), whose
/// name every message starts with.
pub fn check_output_file(option: &str, path: &Path, inputs: &[PathBuf]) -> Result<(), String> {
    let shown = path.display();
    if path.is_dir() {
        return Err(format!(
            "{option} {shown}: is a directory; give a file name such as {shown}/{}",
            match option {
                "--csv" => "walk.csv",
                "--image" => "frame.png",
                _ => "material.nmat",
            }
        ));
    }
    if let Ok(out) = path.canonicalize()
        && inputs.iter().any(|i| i.canonicalize().is_ok_and(|i| i == out))
    {
        return Err(format!("{option} {shown}: is one of the inputs; choose another output name"));
    }
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !dir.is_dir() {
        return Err(format!("{option} {shown}: folder {} does not exist", dir.display()));
    }
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let (tmp, f) = create_exclusive(dir, &name)
        .map_err(|e| format!("{option} {shown}: cannot create a file in {}: {e}", dir.display()))?;
    drop(f);
    let _ = std::fs::remove_file(tmp);
    Ok(())
}

/// A new file `.NAME.tmp-RANDOM` in `dir`, created with `create_new` (fails on any existing
/// entry, symlinks included); a few names are tried.
fn create_exclusive(dir: &Path, name: &str) -> std::io::Result<(PathBuf, std::fs::File)> {
    let open = |p: &Path| std::fs::OpenOptions::new().write(true).create_new(true).open(p);
    new_entry(dir, &format!(".{name}.tmp"), open)
}

/// Creates a new entry `PREFIX-RANDOM` in `dir` with `create` (which must fail on an existing
/// entry); a few random names are tried.
fn new_entry<T>(
    dir: &Path,
    prefix: &str,
    create: impl Fn(&Path) -> std::io::Result<T>,
) -> std::io::Result<(PathBuf, T)> {
    use std::hash::{BuildHasher, Hasher};
    let mut last = None;
    for attempt in 0u32..16 {
        // RandomState is seeded from the OS's randomness once per process, then varied per call.
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u32(attempt);
        h.write_u32(std::process::id());
        let path = dir.join(format!("{prefix}-{:016x}", h.finish()));
        match create(&path) {
            Ok(t) => return Ok((path, t)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last.unwrap_or_else(|| std::io::Error::other("no free temporary name")))
}

/// Runs `write` on a new hidden folder inside `dir` (which is created if missing), then moves the
/// files it wrote into `dir` — all of them or none. A `write` that fails half-way leaves nothing
/// behind: its files are removed, and so is `dir` if this call created it. Before any file is
/// moved, every name is checked (an existing folder or device there is an error); a file that
/// is replaced is first put aside in the staging folder and put back if a later move fails. The
/// staging folder is removed on Ctrl-C, `kill` or a closed terminal too once the binary called
/// [`clean_up_on_signal`], and a staging folder left by a process that no longer runs (killed
/// with SIGKILL, or a crash) is removed by the next write into `dir` (Linux, where `/proc` tells).
pub fn write_all_or_nothing(
    dir: &Path,
    write: impl FnOnce(&Path) -> Result<Vec<PathBuf>, Box<dyn std::error::Error>>,
) -> Result<Vec<PathBuf>, Box<dyn std::error::Error>> {
    let shown = dir.display();
    let existed = match std::fs::metadata(dir) {
        Ok(meta) if meta.is_dir() => true,
        Ok(_) => {
            return Err(format!(
                "-o {shown}: is a file, not a folder; the output is one file per map or texture, \
                 written into a folder: give a folder name"
            )
            .into());
        }
        Err(_) => false,
    };
    std::fs::create_dir_all(dir).map_err(|e| format!("-o {shown}: {e}"))?;
    remove_abandoned_staging(dir);
    let prefix = format!("{STAGING_PREFIX}{}", std::process::id());
    let staging = match new_entry(dir, &prefix, |p| std::fs::create_dir(p)) {
        Ok((path, ())) => path,
        Err(e) => {
            if !existed {
                let _ = std::fs::remove_dir(dir);
            }
            return Err(format!("-o {shown}: cannot create a folder in it: {e}").into());
        }
    };
    let removed_on_signal = (staging.clone(), (!existed).then(|| dir.to_path_buf()));
    lock_staging().push(removed_on_signal.clone());
    let moved = write(&staging).and_then(|files| move_all(dir, &staging, &files));
    let _ = std::fs::remove_dir_all(&staging);
    if moved.is_err() && !existed {
        let _ = std::fs::remove_dir(dir);
    }
    lock_staging().retain(|s| *s != removed_on_signal);
    moved
}

/// Moves `files` (in `staging`) into `dir`: every destination is checked first, a file replaced
/// is put aside in `staging`, and a failed move puts everything back as it was.
fn move_all(
    dir: &Path,
    staging: &Path,
    files: &[PathBuf],
) -> Result<Vec<PathBuf>, Box<dyn std::error::Error>> {
    let targets: Vec<PathBuf> =
        files.iter().map(|f| dir.join(f.file_name().unwrap_or_default())).collect();
    for to in &targets {
        if let Ok(meta) = to.symlink_metadata()
            && !meta.is_file()
            && !meta.is_symlink()
        {
            return Err(format!(
                "{}: is a folder or a device, not a file nmat can replace; nothing was written",
                to.display()
            )
            .into());
        }
    }
    // (new file, destination, the file it replaced put aside)
    let mut done: Vec<(&PathBuf, &PathBuf, Option<PathBuf>)> = Vec::new();
    let mut result = Ok(());
    for (i, (file, to)) in files.iter().zip(&targets).enumerate() {
        let aside = staging.join(format!(".replaced-{i}"));
        let had = to.symlink_metadata().is_ok();
        if had && let Err(e) = std::fs::rename(to, &aside) {
            result = Err(format!("{}: {e}", to.display()));
            break;
        }
        if let Err(e) = std::fs::rename(file, to) {
            if had {
                let _ = std::fs::rename(&aside, to);
            }
            result = Err(format!("{}: {e}; nothing was written", to.display()));
            break;
        }
        done.push((file, to, had.then_some(aside)));
    }
    if let Err(e) = result {
        for (file, to, aside) in done.into_iter().rev() {
            let _ = std::fs::rename(to, file);
            if let Some(aside) = aside {
                let _ = std::fs::rename(aside, to);
            }
        }
        return Err(e.into());
    }
    Ok(targets)
}

/// Names of staging folders: `.nmat-decode-PID-RANDOM`.
const STAGING_PREFIX: &str = ".nmat-decode-";

/// Staging folders in use by this process, each with the output folder it created (if any): what
/// a signal removes.
type Staging = (PathBuf, Option<PathBuf>);

static STAGING: std::sync::Mutex<Vec<Staging>> = std::sync::Mutex::new(Vec::new());

fn lock_staging() -> std::sync::MutexGuard<'static, Vec<Staging>> {
    STAGING.lock().unwrap_or_else(|e| e.into_inner())
}

/// Makes Ctrl-C (SIGINT), `kill` (SIGTERM) and a closed terminal (SIGHUP) remove the staging
/// folders of the writes in progress (and the output folders they created) before the process
/// exits with status 130, so an interrupted decode or transcode leaves nothing behind. For the
/// `nmat` binary; a library user keeps its own signal handling.
pub fn clean_up_on_signal() {
    // The handler runs on a thread of its own, not in signal context: it may lock and remove.
    let _ = ctrlc::set_handler(|| {
        // Workers may still be writing: two passes catch a file created during the first.
        for _ in 0..2 {
            for (staging, created) in lock_staging().iter() {
                let _ = std::fs::remove_dir_all(staging);
                if let Some(dir) = created {
                    let _ = std::fs::remove_dir(dir);
                }
            }
        }
        eprintln!("nmat: interrupted; nothing was written");
        std::process::exit(130);
    });
}

/// Removes the staging folders in `dir` whose process no longer runs (Linux: no `/proc/PID`).
fn remove_abandoned_staging(dir: &Path) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix(STAGING_PREFIX)) else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if pid != std::process::id() && !Path::new("/proc").join(pid.to_string()).exists() {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// The SOURCE_MAPS section of `m`: `Ok(None)` when the file has none, `Err(why)` when it is
/// damaged — unreadable, listing no maps, pointing outside the material's channels, or naming one
/// file twice. The section is optional: every command ignores a damaged one the same way
/// ([`source_maps()`] gives `None`, maps are named after the channels) and says so once
/// ([`damaged_sections`]).
pub fn source_maps_checked(m: &Material<'_>) -> Result<Option<Vec<SourceMap>>, String> {
    let Some(bytes) = m.optional_section(SectionKind(source_maps::SECTION_KIND)) else {
        return Ok(None);
    };
    let maps = source_maps::decode(bytes)
        .ok_or("it cannot be read (an unknown version, a bad name or a record past its end)")?;
    if maps.is_empty() {
        return Err("it lists no maps".into());
    }
    let mut names: Vec<String> = Vec::new();
    for map in &maps {
        let end = map.first_channel + map.channel_count;
        if map.channel_count == 0 || end > m.channel_count() {
            return Err(format!(
                "map {}: channels {}..{end} are not within the material's {} channels",
                map.file_name,
                map.first_channel,
                m.channel_count()
            ));
        }
        // Case-insensitive file systems (Windows, macOS) hold one of `A.png` and `a.png`.
        let name = map.file_name.to_lowercase();
        if names.contains(&name) {
            return Err(format!("it names {} twice", map.file_name));
        }
        names.push(name);
    }
    Ok(Some(maps))
}

/// The SOURCE_MAPS section of `m` if it has a valid one.
pub fn source_maps(m: &Material<'_>) -> Option<Vec<SourceMap>> {
    source_maps_checked(m).ok().flatten()
}

/// What every command says about the optional sections of the file at `path` that are damaged
/// and so ignored (one line each; none for a sound file).
pub fn damaged_sections(path: &Path, m: &Material<'_>) -> Vec<String> {
    match source_maps_checked(m) {
        Err(why) => vec![format!(
            "warning: {}: its SOURCE_MAPS section (optional: the names and layouts of the source \
             maps) is damaged: {why}; ignored, maps are named after the channels",
            path.display()
        )],
        Ok(_) => Vec::new(),
    }
}

/// Maps by channel-name stem (`albedo.r/g/b` → one RGB map) for files without SOURCE_MAPS; the
/// stems made safe file names ([`nmat_encode::names::file_name`]), a number added to a stem
/// already taken.
fn maps_from_names(m: &Material<'_>) -> Vec<SourceMap> {
    let mut maps: Vec<SourceMap> = Vec::new();
    let mut stems: Vec<String> = Vec::new();
    for (c, ch) in m.channels().iter().enumerate() {
        let stem = ch.name.split('.').next().unwrap_or(ch.name);
        match (maps.last_mut(), stems.last()) {
            (Some(last), Some(s)) if s == stem && last.channel_count < 4 => last.channel_count += 1,
            _ => {
                let safe = nmat_encode::names::file_name(stem);
                let taken = |n: &str| maps.iter().any(|m| m.file_name.eq_ignore_ascii_case(n));
                let mut file_name = format!("{safe}.png");
                let mut k = 2;
                while taken(&file_name) {
                    file_name = format!("{safe}-{k}.png");
                    k += 1;
                }
                stems.push(stem.to_string());
                maps.push(SourceMap {
                    role: Role::from_semantic(ch.semantic).unwrap_or(Role::Albedo),
                    file_name,
                    layout: FileLayout::Gray,
                    first_channel: c,
                    channel_count: 1,
                    gray_rgb: false,
                    alpha_value: None,
                    sixteen_bit: false,
                })
            }
        }
    }
    for map in &mut maps {
        map.layout = [FileLayout::Gray, FileLayout::GrayAlpha, FileLayout::Rgb, FileLayout::Rgba]
            [map.channel_count - 1];
    }
    maps
}

/// Writes mip 0 of every map of `set` as an 8-bit PNG under its source name into `dir` (created if
/// missing): the maps of a generated material (`nmat demo`) as files `encode`, `eval` and `bench`
/// can read. Every component must be stored in the set (no constant alpha, no gray-as-RGB), as the
/// demo's maps are.
pub fn write_source_maps(
    set: &TextureSet,
    dir: &Path,
) -> Result<Vec<PathBuf>, Box<dyn std::error::Error>> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let (mip, c) = (&set.mips[0], set.channel_count());
    let mut written = Vec::new();
    for map in &set.maps {
        let comps = map.layout.components();
        if map.channel_count != comps || map.alpha_value.is_some() || map.gray_rgb {
            return Err(format!("{}: a map with components not stored", map.file_name).into());
        }
        let px: Vec<u16> = mip
            .data
            .chunks_exact(c)
            .flat_map(|t| &t[map.first_channel..map.first_channel + comps])
            .map(|&u| (u * 255.0).round().clamp(0.0, 255.0) as u16)
            .collect();
        let name = Path::new(&map.file_name).with_extension("png");
        let image = to_image(mip.width, mip.height, map.layout, false, px);
        let path = dir.join(name);
        write_atomic(&path, &encode_image(image, ImageFormat::Png)?)?;
        written.push(path);
    }
    Ok(written)
}

/// Output name and format of one map at one mip. Lossy formats are not re-encoded lossily (they
/// come back as PNG); `png` writes every map as PNG.
fn output_name(file_name: &str, mip: u32, single_mip0: bool, png: bool) -> (String, ImageFormat) {
    let path = Path::new(file_name);
    let stem =
        path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "map".into());
    let ext =
        path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let (ext, format) = match ext.as_str() {
        _ if png => ("png", ImageFormat::Png),
        "tga" => ("tga", ImageFormat::Tga),
        "bmp" => ("bmp", ImageFormat::Bmp),
        "tif" | "tiff" => (if ext == "tif" { "tif" } else { "tiff" }, ImageFormat::Tiff),
        _ => ("png", ImageFormat::Png),
    };
    let name = if single_mip0 && mip == 0 {
        format!("{stem}.{ext}")
    } else {
        format!("{stem}_mip{mip}.{ext}")
    };
    (name, format)
}

/// Whether `format` can store a map of `layout` at the depth `write_maps` gives it (TGA and BMP
/// have no 16-bit modes: those maps are written as 8-bit RGBA).
fn format_holds(format: ImageFormat, layout: FileLayout) -> bool {
    !(format == ImageFormat::Tiff && layout == FileLayout::GrayAlpha)
}

/// What `nmat decode` writes — the maps, the mips, each file's name and format — checked before
/// any texel is decoded, so a file that cannot be written back whole writes nothing.
pub struct DecodePlan {
    maps: Vec<SourceMap>,
    mips: Vec<u32>,
    /// Every map as PNG, whatever its original format.
    png: bool,
}

impl DecodePlan {
    /// The mips to decode, in the order they are written.
    pub fn mips(&self) -> &[u32] {
        &self.mips
    }

    /// The maps of the file's SOURCE_MAPS section, or maps by channel-name stem for a file
    /// without a valid one ([`source_maps()`]); each output file must be named once, in a format
    /// that holds its layout.
    pub fn new(m: &Material<'_>, mips: &[u32], png: bool) -> Result<DecodePlan, String> {
        let maps = source_maps(m).unwrap_or_else(|| maps_from_names(m));
        let plan = DecodePlan { maps, mips: mips.to_vec(), png };
        let mut names: Vec<String> = Vec::new();
        for map in &plan.maps {
            let name = &map.file_name;
            for (file, format) in plan.files_of(map) {
                if !format_holds(format, map.layout) {
                    return Err(format!(
                        "source map {name}: {format:?} cannot hold a {} map; nothing was \
                         written. Pass --png to write every map as PNG",
                        layout_words(map.layout)
                    ));
                }
                if names.contains(&file) {
                    return Err(format!(
                        "the file's source maps name {file} twice ({name}); nothing was written"
                    ));
                }
                names.push(file);
            }
        }
        Ok(plan)
    }

    /// File name and format of `map` at `mip`.
    fn file_of(&self, map: &SourceMap, mip: u32) -> (String, ImageFormat) {
        output_name(&map.file_name, mip, self.mips == [0], self.png)
    }

    /// File name and format of `map` at each mip, in mip order.
    fn files_of(&self, map: &SourceMap) -> Vec<(String, ImageFormat)> {
        self.mips.iter().map(|&mip| self.file_of(map, mip)).collect()
    }

    /// Every file the decode writes, map by map.
    pub fn file_names(&self) -> Vec<String> {
        self.maps.iter().flat_map(|map| self.files_of(map)).map(|(name, _)| name).collect()
    }

    /// Texels the decode evaluates (each once, for all channels) and the network's multiply-adds.
    pub fn cost(&self, m: &Material<'_>) -> DecodeCost {
        cost_of_mips(m, self.mips.iter().copied())
    }

    /// Memory the decode needs at most: every map of the largest mip as 16-bit components, and
    /// once more while one of them is converted and encoded.
    pub fn memory(&self, m: &Material<'_>) -> u64 {
        let components: u64 = self.maps.iter().map(|p| p.layout.components() as u64).sum();
        let largest = self.mips.iter().map(|&mip| m.decode_cost(mip).texels).max().unwrap_or(0);
        largest.saturating_mul(components + 4).saturating_mul(2)
    }
}

fn layout_words(layout: FileLayout) -> &'static str {
    match layout {
        FileLayout::Gray => "gray",
        FileLayout::GrayAlpha => "gray+alpha",
        FileLayout::Rgb => "RGB",
        FileLayout::Rgba => "RGBA",
    }
}

/// 8-bit codes of every channel of a whole mip, row-major, decoded elsewhere (the GPU).
pub type MipDecoder<'d> = dyn Fn(u32) -> Result<Vec<u8>, Box<dyn std::error::Error>> + 'd;

/// How `write_maps` decodes.
#[derive(Clone, Copy, Default)]
pub struct DecodeWith<'d> {
    /// The float reference decoder instead of the integer-exact one.
    pub float: bool,
    /// Whole mips decoded elsewhere (8-bit codes; 16-bit maps come back at 8 bits from it).
    pub batch: Option<&'d MipDecoder<'d>>,
}

/// Decodes the plan's mips of every map and writes them into `dir` under their original names
/// (mip by mip: each texel is decoded once for all channels). `progress` receives the texels
/// done after each row. Returns the files written, in the plan's order.
pub fn write_maps(
    m: &Material<'_>,
    plan: &DecodePlan,
    dir: &Path,
    with: DecodeWith<'_>,
    progress: &mut dyn FnMut(u64),
) -> Result<Vec<PathBuf>, Box<dyn std::error::Error>> {
    let channels = m.channel_count();
    let decoder = Decoder::new(m);
    let all = ChannelMask::ALL;
    let sixteen_of = |map: &SourceMap| map.sixteen_bit && !with.float && with.batch.is_none();
    let (need8, need16) =
        (plan.maps.iter().any(|p| !sixteen_of(p)), plan.maps.iter().any(sixteen_of));
    let mut written: Vec<Vec<PathBuf>> = vec![Vec::new(); plan.maps.len()];
    for &mip in &plan.mips {
        let (w, h) = m.mip_size(mip);
        let (wu, hu) = (w as usize, h as usize);
        let batched = match with.batch {
            Some(decode) if !with.float => Some(decode(mip)?),
            _ => None,
        };
        let mut pixels: Vec<Vec<u16>> =
            plan.maps.iter().map(|p| Vec::with_capacity(wu * hu * p.layout.components())).collect();
        // Unit values of every channel of one row: from 8-bit codes, 16-bit codes, or floats.
        let mut unit8 = vec![0f32; wu * channels];
        let mut unit16 = vec![0f32; wu * channels];
        let mut codes8 = vec![0u8; wu * channels];
        let mut codes16 = vec![0u16; wu * channels];
        for y in 0..hu {
            if let Some(all_codes) = &batched {
                let row = all_codes.get(y * wu * channels..(y + 1) * wu * channels);
                let row = row.ok_or("the GPU decoder returned fewer codes than the mip has")?;
                unit8.iter_mut().zip(row).for_each(|(u, &c)| *u = f32::from(c) / 255.0);
            } else if with.float {
                for (x, u) in unit8.chunks_exact_mut(channels).enumerate() {
                    m.decode_texel_unit(x as i64, y as i64, mip, all, u)?;
                }
            } else {
                if need8 {
                    decoder.decode_span_u8(m, 0, y as i64, mip, wu, all, &mut codes8)?;
                    unit8.iter_mut().zip(&codes8).for_each(|(u, &c)| *u = f32::from(c) / 255.0);
                }
                if need16 {
                    decoder.decode_span_u16(m, 0, y as i64, mip, wu, all, &mut codes16)?;
                    let scale = |(u, &c): (&mut f32, &u16)| *u = f32::from(c) / 65535.0;
                    unit16.iter_mut().zip(&codes16).for_each(scale);
                }
            }
            for (map, px) in plan.maps.iter().zip(&mut pixels) {
                let sixteen = sixteen_of(map);
                let unit = if sixteen { &unit16 } else { &unit8 };
                for texel in unit.chunks_exact(channels) {
                    push_texel(m, map, sixteen, texel, px);
                }
            }
            progress(u64::from(w));
        }
        for ((map, px), files) in plan.maps.iter().zip(pixels).zip(&mut written) {
            let (name, format) = plan.file_of(map, mip);
            let image = to_image(w, h, map.layout, sixteen_of(map), px);
            let bytes = encode_image(image, format).map_err(|e| format!("{name}: {e}"))?;
            let path = dir.join(name);
            write_atomic(&path, &bytes)?;
            files.push(path);
        }
    }
    Ok(written.into_iter().flatten().collect())
}

/// Appends one texel of `map` to its pixels: `texel` holds the unit values of every channel.
fn push_texel(m: &Material<'_>, map: &SourceMap, sixteen: bool, texel: &[f32], px: &mut Vec<u16>) {
    let comps = map.layout.components();
    let full = if sixteen { 65535.0 } else { 255.0 };
    let value = |k: usize| {
        let c = map.first_channel + k;
        let Some(&decoded) = texel.get(c) else { return full as u16 };
        (unit_of(m, c, decoded) * full).round().clamp(0.0, full) as u16
    };
    let start = px.len();
    if map.gray_rgb {
        px.extend([value(0); 3].iter().take(comps));
    } else {
        px.extend((0..map.channel_count.min(comps)).map(value));
    }
    if let Some(a) = map.alpha_value {
        px.push(if sixteen { u16::from(a) * 257 } else { u16::from(a) });
    } else if map.gray_rgb && comps == 4 {
        px.push(value(1));
    }
    px.truncate(start + comps);
    px.resize(start + comps, full as u16);
}

/// The bytes of `image` in `format`. TGA and BMP have no 16-bit modes: 16-bit maps are written to
/// them as 8-bit RGBA.
fn encode_image(image: image::DynamicImage, format: ImageFormat) -> image::ImageResult<Vec<u8>> {
    let sixteen = image.color().bytes_per_pixel() > image.color().channel_count();
    let image = if sixteen && format != ImageFormat::Png && format != ImageFormat::Tiff {
        image::DynamicImage::from(image.to_rgba8())
    } else {
        image
    };
    let mut buffer = std::io::Cursor::new(Vec::new());
    image.write_to(&mut buffer, format)?;
    Ok(buffer.into_inner())
}

fn to_image(w: u32, h: u32, layout: FileLayout, sixteen: bool, p: Vec<u16>) -> image::DynamicImage {
    use image::{DynamicImage as D, ImageBuffer};
    macro_rules! buf {
        ($px:ty, $data:expr) => {
            ImageBuffer::<$px, _>::from_raw(w, h, $data).unwrap_or_else(|| ImageBuffer::new(w, h))
        };
    }
    if sixteen {
        match layout {
            FileLayout::Gray => D::ImageLuma16(buf!(image::Luma<u16>, p)),
            FileLayout::GrayAlpha => D::ImageLumaA16(buf!(image::LumaA<u16>, p)),
            FileLayout::Rgb => D::ImageRgb16(buf!(image::Rgb<u16>, p)),
            FileLayout::Rgba => D::ImageRgba16(buf!(image::Rgba<u16>, p)),
        }
    } else {
        let p: Vec<u8> = p.into_iter().map(|v| v.min(255) as u8).collect();
        match layout {
            FileLayout::Gray => D::ImageLuma8(buf!(image::Luma<u8>, p)),
            FileLayout::GrayAlpha => D::ImageLumaA8(buf!(image::LumaA<u8>, p)),
            FileLayout::Rgb => D::ImageRgb8(buf!(image::Rgb<u8>, p)),
            FileLayout::Rgba => D::ImageRgba8(buf!(image::Rgba<u8>, p)),
        }
    }
}

/// `nmat info`: `m` read from a file `stored` so (a packed file's sizes and version are the
/// file's; `m` is its fixed-rate form in memory).
pub fn describe(path: &Path, m: &Material<'_>, stored: Stored) -> String {
    let mut s = String::new();
    let _ = write!(
        s,
        "{}: .nmat format {}.{}, {} bytes",
        path.display(),
        m.version_major(),
        stored.minor,
        stored.len
    );
    if stored.packed {
        let _ = write!(
            s,
            " ({}: {:.3} of the {} bytes it takes in memory, fixed-rate)",
            if m.jpeg().is_some() {
                "streams without their index, rebuilt when opened"
            } else {
                "latents entropy-coded"
            },
            stored.len as f64 / m.file_len() as f64,
            m.file_len()
        );
    }
    let _ = writeln!(s);
    let constant = m.channels().iter().filter(|c| c.range_min == c.range_max).count();
    let _ = write!(
        s,
        "size {}×{}, {} mips, {} channels, {:?} addressing, {:.4} bits per pixel per channel",
        m.width(),
        m.height(),
        m.mip_count(),
        m.channel_count(),
        m.address_mode(),
        m.bppc_of(stored.len)
    );
    if stored.packed {
        let _ = write!(s, " ({:.4} in memory)", m.bppc());
    }
    if constant > 0 {
        let _ = write!(
            s,
            " over the {} channels that vary ({constant} constant, stored as their value)",
            m.informative_channels()
        );
    }
    let _ = writeln!(s);
    let _ = writeln!(s, "\nchannels:");
    for (i, c) in m.channels().iter().enumerate() {
        let role = Role::from_semantic(c.semantic).map_or("other", |r| r.name());
        let constant = if c.range_min == c.range_max {
            format!(" constant {}", c.range_min)
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "  {i:2} {:12} {role:10} {:?} [{}, {}]{constant}",
            nmat_encode::names::for_terminal(c.name),
            c.color_space,
            c.range_min,
            c.range_max
        );
    }
    if let Some(maps) = source_maps(m) {
        s.push_str(&map_lines(&maps));
    }
    let n = match m.body() {
        Body::Jpeg(jpeg) => {
            s.push_str(&jpeg_lines(m, jpeg, stored));
            return s;
        }
        Body::Neural(n) => n,
    };
    let _ = writeln!(s, "\nlatent grids:");
    for (i, g) in n.grids().iter().enumerate() {
        let _ = writeln!(
            s,
            "  {i:2} {:5}×{:<5} {:2} channels × {} bits  {:8} bytes",
            g.width(),
            g.height(),
            g.channels(),
            g.bits_per_latent(),
            g.packed_data().len()
        );
    }
    for (l, level) in n.levels().iter().enumerate() {
        let mips = (0..m.mip_count()).filter(|&k| n.level_for_mip(k) == l);
        let terms = level.terms.iter().map(|t| format!("{:?}{:?}", t.mode, t.grids.as_slice()));
        s.push_str(&level_line(l, mips, terms));
    }
    let mlp = n.mlp();
    let shape: Vec<String> =
        mlp.layers().iter().map(|l| format!("{}→{}", l.inputs(), l.outputs())).collect();
    let _ = writeln!(
        s,
        "\nMLP {} ({} MACs/texel), input Q.{}, {} PE frequencies, LOD input {}",
        shape.join(", "),
        mlp.macs_per_texel(),
        mlp.input_frac_bits(),
        mlp.pe_frequencies(),
        // Code c: mip · 2^(c − 5).
        match mlp.lod_code() {
            0 => "none".to_string(),
            5 => "mip".to_string(),
            c => format!("mip/{}", 1u32 << (5 - c)),
        }
    );
    s.push_str(&budget_table(&file_budget(m), texel_channels(m)));
    s
}

/// The maps of a JPEG material and what its index costs.
fn jpeg_lines(m: &Material<'_>, jpeg: &nmat_core::Jpeg<'_>, stored: Stored) -> String {
    let mut s = String::from("\nindexed JPEG maps (one stream per mip):\n");
    let index_kept = if stored.packed { "rebuilt when opened" } else { "in the file" };
    for (i, map) in jpeg.maps().iter().enumerate() {
        let layout = if map.channel_count == 3 {
            format!("YCbCr, {}×{} luma per chroma sample", map.luma_h, map.luma_v)
        } else {
            "gray".to_string()
        };
        let (w, h) = map.mcu_size();
        let last = map.first_channel + map.channel_count - 1;
        let _ = writeln!(s, "  channels {}..{}: {layout}, MCU {w}×{h}", map.first_channel, last);
        let _ = writeln!(
            s,
            "    {:>4} {:>11} {:>7} {:>12} {:>16} {:>14}",
            "mip", "size", "MCUs", "data bytes", "index+DC bytes", "bits/texel"
        );
        for mip in 0..m.mip_count() {
            let (extra, coded) = jpeg.stream_overhead_bits(i, mip);
            let (mw, mh) = m.mip_size(mip);
            let (mx, my) = jpeg.mcu_grid(i, mip);
            let texels = f64::from(mw) * f64::from(mh);
            let _ = writeln!(
                s,
                "    {mip:>4} {:>11} {:>7} {:>12} {:>16} {:>6.3} + {:.3}",
                format!("{mw}×{mh}"),
                mx * my,
                coded / 8,
                extra.div_ceil(8),
                coded as f64 / texels,
                extra as f64 / texels
            );
        }
    }
    let (extra, coded) = jpeg.overhead_bits();
    let texels: f64 = (0..m.mip_count())
        .map(|k| {
            let (w, h) = m.mip_size(k);
            f64::from(w) * f64::from(h)
        })
        .sum();
    let _ = writeln!(
        s,
        "  entropy-coded data {} bytes; index and DC values {} bytes, {index_kept} ({:.3} bits per \
         texel of the chain)",
        coded / 8,
        extra.div_ceil(8),
        extra as f64 / texels
    );
    let section = m.section_len(SectionKind::JPEG).unwrap_or(0);
    let _ = writeln!(
        s,
        "  JPEG section {section} bytes in memory ({:.4} BPPC) of the fixed-rate file's {}",
        m.bppc_of(section),
        m.file_len()
    );
    s
}

/// BPPC's denominator: width · height · channels that vary, of mip 0.
pub fn texel_channels(m: &Material<'_>) -> f64 {
    f64::from(m.width()) * f64::from(m.height()) * m.informative_channels() as f64
}

/// A level of a neural material, as `nmat info` and `nmat encode --dry-run` list it: its mips and
/// the terms that read its grids (`  level 0 (mips 0,1,2): Nearest4[0] + Bilinear[1]`).
pub fn level_line(
    level: usize,
    mips: impl Iterator<Item = u32>,
    terms: impl Iterator<Item = String>,
) -> String {
    let mips: Vec<String> = mips.map(|k| k.to_string()).collect();
    let terms: Vec<String> = terms.collect();
    format!("  level {level} (mips {}): {}\n", mips.join(","), terms.join(" + "))
}

/// The source maps and the channels each one occupies, as `info` and `encode --dry-run` print them.
pub fn map_lines(maps: &[SourceMap]) -> String {
    let mut s = String::from("\nsource maps:\n");
    for map in maps {
        let _ = writeln!(
            s,
            "  {:28} {:9} {:?}{}{} → channels {}..{}",
            map.file_name,
            map.role.name(),
            map.layout,
            if map.sixteen_bit { " 16-bit" } else { "" },
            if map.gray_rgb { " (R = G = B, stored once)" } else { "" },
            map.first_channel,
            map.first_channel + map.channel_count - 1
        );
    }
    s
}

/// Where the bytes of a parsed file go, by section (header = header, section table, padding).
pub fn file_budget(m: &Material<'_>) -> ByteBudget {
    let len = |k| m.section_len(k).unwrap_or(0);
    let optional: usize = m.optional_sections().iter().map(|(_, d)| d.len()).sum();
    let b = ByteBudget {
        header: 0,
        material: len(SectionKind::MATERIAL),
        levels: len(SectionKind::LEVELS),
        network: len(SectionKind::MLP),
        latents: len(SectionKind::LATENTS),
        optional,
    };
    ByteBudget { header: m.file_len().saturating_sub(b.total()), ..b }
}

/// The byte budget as `info` and `encode --dry-run` print it: bytes, share of the file and bits
/// per pixel per channel of each part (`texel_channels` = width · height · channels of mip 0).
pub fn budget_table(b: &ByteBudget, texel_channels: f64) -> String {
    let total = b.total().max(1);
    let mut s = String::from("\nbyte budget:\n");
    for (name, bytes) in [
        ("latents", b.latents),
        ("network (int8 weights, row scales, biases)", b.network),
        ("grid and level records", b.levels),
        ("channel records", b.material),
        ("header and section table", b.header),
        ("source maps", b.optional),
        ("file", b.total()),
    ] {
        let _ = writeln!(
            s,
            "  {name:44} {bytes:9} bytes  {:5.1} %  {:.4} BPPC",
            100.0 * bytes as f64 / total as f64,
            bytes as f64 * 8.0 / texel_channels.max(1.0)
        );
    }
    s
}

/// The quality report of `encode`, `eval` and `demo`.
pub fn quality_table(set: &TextureSet, q: &ChainQuality, setting: Option<&str>) -> String {
    let mut s = String::new();
    if let Some(line) = setting {
        let _ = writeln!(s, "{line}");
    }
    let _ = writeln!(
        s,
        "{:28} {:>10} {}",
        "map",
        "chain dB",
        (0..set.mips.len()).map(|m| format!("{:>7}", format!("mip{m}"))).collect::<String>()
    );
    for map in &set.maps {
        let chans: Vec<usize> =
            (map.first_channel..map.first_channel + map.channel_count).collect();
        let _ = write!(s, "{:28} {:>10.2}", map.file_name, q.psnr_of(&chans, None, set));
        for m in 0..set.mips.len() {
            let _ = write!(s, "{:>7.2}", q.psnr_of(&chans, Some(m), set));
        }
        let _ = writeln!(s);
    }
    let _ = write!(
        s,
        "overall: PSNR {:.2} dB over all channels and mips, SSIM {:.4} at mip 0, {:.4} bits per pixel per channel",
        q.psnr, q.ssim, q.bppc
    );
    if q.memory_bppc != q.bppc {
        let _ = write!(s, " ({:.4} in memory)", q.memory_bppc);
    }
    let _ = writeln!(s);
    s
}

/// What decoding `mips` of `m` costs, summed.
pub fn cost_of_mips(m: &Material<'_>, mips: impl Iterator<Item = u32>) -> DecodeCost {
    mips.map(|mip| m.decode_cost(mip)).fold(DecodeCost { texels: 0, macs: 0 }, |a, c| DecodeCost {
        texels: a.texels + c.texels,
        macs: a.macs.saturating_add(c.macs),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn a_planted_temporary_symlink_does_not_redirect_the_write() {
        let dir = std::env::temp_dir().join(format!("nmat-atomic-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let victim = dir.join("victim.txt");
        std::fs::write(&victim, b"keep me").unwrap();
        // The names an earlier version used (`.NAME.tmp-PID`) and a spread of guesses.
        for suffix in [std::process::id().to_string(), "0".into(), "1".into()] {
            let link = dir.join(format!(".out.nmat.tmp-{suffix}"));
            std::os::unix::fs::symlink(&victim, link).unwrap();
        }
        let out = dir.join("out.nmat");
        write_atomic(&out, b"new bytes").unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"keep me");
        assert!(std::fs::symlink_metadata(&out).unwrap().file_type().is_file());
        assert_eq!(std::fs::read(&out).unwrap(), b"new bytes");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn format_holds_agrees_with_the_image_encoders() {
        use FileLayout::*;
        for format in [ImageFormat::Png, ImageFormat::Tga, ImageFormat::Bmp, ImageFormat::Tiff] {
            for layout in [Gray, GrayAlpha, Rgb, Rgba] {
                for sixteen in [false, true] {
                    let px = vec![1000u16; 4 * 3 * layout.components()];
                    let written = encode_image(to_image(4, 3, layout, sixteen, px), format);
                    assert_eq!(
                        written.is_ok(),
                        format_holds(format, layout),
                        "{format:?} {layout:?} 16-bit {sixteen}: {written:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_write_that_fails_half_way_leaves_nothing_and_one_that_succeeds_moves_every_file() {
        let base = std::env::temp_dir().join(format!("nmat-all-or-nothing-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let out = base.join("new");
        let result = write_all_or_nothing(&out, |dir| {
            std::fs::write(dir.join("a.png"), b"first")?;
            Err("the second map failed".into())
        });
        assert!(result.is_err());
        assert!(!out.exists(), "the output folder this call created was left behind");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("keep.txt"), b"mine").unwrap();
        let result = write_all_or_nothing(&out, |dir| {
            std::fs::write(dir.join("a.png"), b"first")?;
            Err("the second map failed".into())
        });
        assert!(result.is_err());
        let names = |d: &Path| -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(d)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        };
        assert_eq!(names(&out), ["keep.txt"], "a half-written decode was left");
        let written = write_all_or_nothing(&out, |dir| {
            std::fs::write(dir.join("a.png"), b"first")?;
            std::fs::write(dir.join("b.png"), b"second")?;
            Ok(vec![dir.join("a.png"), dir.join("b.png")])
        })
        .unwrap();
        assert_eq!(written, [out.join("a.png"), out.join("b.png")]);
        assert_eq!(names(&out), ["a.png", "b.png", "keep.txt"]);
        assert_eq!(std::fs::read(out.join("b.png")).unwrap(), b"second");
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn a_failed_write_leaves_no_temporary_file() {
        let dir = std::env::temp_dir().join(format!("nmat-atomic-fail-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("out.nmat")).unwrap();
        // Renaming a file over a non-empty directory fails.
        std::fs::write(dir.join("out.nmat").join("x"), b"").unwrap();
        let err = write_atomic(&dir.join("out.nmat"), b"bytes").unwrap_err();
        assert!(err.to_string().contains("out.nmat"), "{err}");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 1, "only the directory remains");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
