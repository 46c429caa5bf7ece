//! `nmat transcode`: a material's maps as BC textures (the whole mip chain) in KTX2 or DDS files.

use crate::gpu_files::{self, BcImage};
use nmat_core::bc::{self, BcFormat, BcTexture, MapChannels};
use nmat_core::{BlockRegion, Decoder, Material, Semantic};
use rayon::prelude::*;

/// Which formats the maps get: one for every map (`None`: from each map's meaning), and the
/// maps of some semantics in their own.
#[derive(Clone, Debug, Default)]
pub struct Choice {
    pub all: Option<BcFormat>,
    pub by_semantic: Vec<(Semantic, BcFormat)>,
}

/// A texture to write and the stem of its file name (`albedo`, `albedo-a`, `normal`, …).
pub struct Named {
    pub texture: BcTexture,
    pub stem: String,
}

/// The textures of `m` under `choice`, each with a file stem unique among them: the name of its
/// map (its first channel's name up to the first '.'), then — for a texture that does not start
/// at a map's first component — that channel's suffix (`albedo-a` for the alpha of `albedo.a`),
/// then a number if still taken.
pub fn plan(m: &Material<'_>, choice: &Choice) -> Vec<Named> {
    let format_of = |map: &MapChannels| {
        let own = choice.by_semantic.iter().find(|(s, _)| *s == map.semantic);
        own.map(|&(_, f)| f).or(choice.all)
    };
    let channel_name = |c: u8| m.channels().get(usize::from(c)).map_or("", |ch| ch.name);
    let mut out: Vec<Named> = Vec::new();
    for map in bc::maps(m) {
        let textures = match format_of(&map) {
            Some(f) => bc::textures_in(&map, f),
            None => bc::auto_textures(&map),
        };
        for texture in textures {
            let first = texture.channels[0];
            let name = channel_name(first);
            let base = name.split('.').next().filter(|b| !b.is_empty()).unwrap_or("channel");
            let mut stem = sanitize(base);
            let component = m.channels().get(usize::from(first)).map_or(0, |c| c.component);
            if first != map.first || component != 0 {
                let part = name.split_once('.').map_or(String::new(), |(_, p)| sanitize(p));
                stem = if part.is_empty() {
                    format!("{stem}-{first}")
                } else {
                    format!("{stem}-{part}")
                };
            }
            let taken = |s: &str| out.iter().any(|n| n.stem == s);
            if taken(&stem) {
                let mut k = 2;
                while taken(&format!("{stem}-{k}")) {
                    k += 1;
                }
                stem = format!("{stem}-{k}");
            }
            out.push(Named { texture, stem });
        }
    }
    out
}

/// A file-name-safe form of a channel name (which the file may set to anything): ASCII letters,
/// digits, '-' and '_' kept, the rest '_', at most 64 bytes.
fn sanitize(name: &str) -> String {
    name.chars()
        .take(64)
        .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' })
        .collect()
}

/// Block rows transcoded between two progress reports.
const BATCH_ROWS: usize = 16;

/// Transcodes every mip of `texture` (block rows in parallel on rayon's threads; the bytes do
/// not depend on how many). `progress` receives the texels done after each batch of rows.
pub fn transcode(
    m: &Material<'_>,
    decoder: &Decoder,
    texture: &BcTexture,
    progress: &mut dyn FnMut(u64),
) -> Result<BcImage, nmat_core::Error> {
    let bytes = texture.format.block_bytes();
    let mut levels = Vec::new();
    for mip in 0..m.mip_count() {
        let all = BlockRegion::mip(m, mip);
        let row = (all.width as usize * bytes).max(1);
        let mut level = vec![0u8; row * all.height as usize];
        let (w, h) = m.mip_size(mip);
        for (b, batch) in level.chunks_mut(row * BATCH_ROWS).enumerate() {
            batch.par_chunks_mut(row).enumerate().try_for_each(|(k, out)| {
                let y = (b * BATCH_ROWS + k) as u32;
                let region = BlockRegion { y, height: 1, ..all };
                decoder.transcode_blocks(m, texture, mip, region, out, row)
            })?;
            let rows = (batch.len() / row * 4) as u32;
            let done = (b * BATCH_ROWS * 4) as u32;
            progress(u64::from(w) * u64::from(rows.min(h.saturating_sub(done))));
        }
        levels.push(level);
    }
    Ok(image(m, texture, levels))
}

/// The image of `texture` from its mips' blocks (e.g. transcoded on the GPU).
pub fn image(m: &Material<'_>, texture: &BcTexture, levels: Vec<Vec<u8>>) -> BcImage {
    BcImage {
        format: texture.format,
        srgb: texture.srgb,
        width: m.width(),
        height: m.height(),
        levels,
    }
}

/// The container a texture is written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Container {
    Ktx2,
    Dds,
}

impl Container {
    pub fn extension(self) -> &'static str {
        match self {
            Container::Ktx2 => "ktx2",
            Container::Dds => "dds",
        }
    }

    pub fn bytes(self, image: &BcImage) -> Vec<u8> {
        match self {
            Container::Ktx2 => gpu_files::ktx2(image),
            Container::Dds => gpu_files::dds(image),
        }
    }
}

/// The file name of a texture: `STEM.FORMAT.EXT` (`albedo.bc1.ktx2`).
pub fn file_name(named: &Named, container: Container) -> String {
    format!("{}.{}.{}", named.stem, named.texture.format.name(), container.extension())
}
