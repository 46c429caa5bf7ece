//! `nmat transcode`: a material's maps as BC textures (the whole mip chain) in KTX2 or DDS files.

use crate::gpu_files::{self, BcImage};
use nmat_core::bc::{self, BcFormat, BcTexture, MapChannels};
use nmat_core::{BcTarget, BlockRegion, Decoder, Material, Semantic};
use nmat_encode::names;
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
            let mut stem = names::file_name(base);
            let component = m.channels().get(usize::from(first)).map_or(0, |c| c.component);
            if first != map.first || component != 0 {
                let part = name
                    .split_once('.')
                    .filter(|(_, p)| !p.is_empty())
                    .map_or(String::new(), |(_, p)| names::file_name(p));
                stem = if part.is_empty() {
                    format!("{stem}-{first}")
                } else {
                    format!("{stem}-{part}")
                };
            }
            // Case-insensitive file systems (Windows, macOS) hold one of `A` and `a`.
            let taken = |s: &str| out.iter().any(|n| n.stem.eq_ignore_ascii_case(s));
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

/// Block rows transcoded between two progress reports.
const BATCH_ROWS: usize = 16;

/// Transcodes every mip of `textures`, all of them in one pass of the network per block row
/// (`Decoder::transcode_textures`; block rows in parallel on rayon's threads; the bytes do not
/// depend on how many). `progress` receives the texels decoded after each batch of rows.
pub fn transcode(
    m: &Material<'_>,
    decoder: &Decoder,
    textures: &[BcTexture],
    progress: &mut dyn FnMut(u64),
) -> Result<Vec<BcImage>, nmat_core::Error> {
    if textures.is_empty() {
        return Ok(Vec::new());
    }
    let mut levels: Vec<Vec<Vec<u8>>> = vec![Vec::new(); textures.len()];
    for mip in 0..m.mip_count() {
        let all = BlockRegion::mip(m, mip);
        let mip_levels = transcode_region(m, decoder, textures, (mip, all), progress)?;
        for (all_levels, level) in levels.iter_mut().zip(mip_levels) {
            all_levels.push(level);
        }
    }
    Ok(textures.iter().zip(levels).map(|(t, l)| image(m, t, l)).collect())
}

/// The blocks of `region` of `mip` of every texture of `textures` (each texture's rows one after
/// the other, without padding), as [`transcode`] makes each mip: one pass of the network per
/// block row, block rows in parallel on rayon's threads. `progress` receives the texels decoded
/// after each batch of rows.
pub fn transcode_region(
    m: &Material<'_>,
    decoder: &Decoder,
    textures: &[BcTexture],
    (mip, region): (u32, BlockRegion),
    progress: &mut dyn FnMut(u64),
) -> Result<Vec<Vec<u8>>, nmat_core::Error> {
    let rows = region.height as usize;
    let row_bytes: Vec<usize> =
        textures.iter().map(|t| region.width as usize * t.format.block_bytes()).collect();
    let mut levels: Vec<Vec<u8>> = row_bytes.iter().map(|r| vec![0u8; r * rows]).collect();
    // Per block row, each texture's slice of it.
    let mut per_row: Vec<Vec<&mut [u8]>> = (0..rows).map(|_| Vec::new()).collect();
    for (level, &row) in levels.iter_mut().zip(&row_bytes) {
        for (slices, chunk) in per_row.iter_mut().zip(level.chunks_mut(row.max(1))) {
            slices.push(chunk);
        }
    }
    let (w, h) = m.mip_size(mip);
    let (x0, y0) = (4 * region.x, 4 * region.y);
    let width = (4 * region.width).min(w.saturating_sub(x0));
    for (b, batch) in per_row.chunks_mut(BATCH_ROWS).enumerate() {
        batch.par_iter_mut().enumerate().try_for_each(|(k, slices)| {
            let y = region.y + (b * BATCH_ROWS + k) as u32;
            let row = BlockRegion { y, height: 1, ..region };
            let mut targets: Vec<BcTarget<'_>> = textures
                .iter()
                .zip(slices.iter_mut())
                .map(|(t, out)| BcTarget { texture: *t, row_pitch: out.len(), out })
                .collect();
            decoder.transcode_textures(m, mip, row, &mut targets)
        })?;
        let texel_rows = (batch.len() * 4) as u32;
        let done = y0 + (b * BATCH_ROWS * 4) as u32;
        let texels = u64::from(width) * u64::from(texel_rows.min(h.saturating_sub(done)));
        progress(texels);
    }
    drop(per_row);
    Ok(levels)
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

/// Bytes a transcode of `textures` holds at most, about: every texture's blocks for the whole
/// chain (they are written when all are done), a file's bytes for the largest, and a pointer per
/// block row and texture of a mip.
pub fn memory(m: &Material<'_>, textures: &[BcTexture]) -> u64 {
    let chain_blocks: u64 = (0..m.mip_count())
        .map(|mip| {
            let (w, h) = m.mip_size(mip);
            u64::from(w.div_ceil(4)) * u64::from(h.div_ceil(4))
        })
        .sum();
    let per_texture: Vec<u64> =
        textures.iter().map(|t| chain_blocks * t.format.block_bytes() as u64).collect();
    let rows = u64::from(m.mip_size(0).1.div_ceil(4)) * 16 * textures.len() as u64;
    per_texture.iter().sum::<u64>() + per_texture.iter().max().unwrap_or(&0) + rows
}

/// The file name of a texture: `STEM.FORMAT.EXT` (`albedo.bc1.ktx2`).
pub fn file_name(named: &Named, container: Container) -> String {
    format!("{}.{}.{}", named.stem, named.texture.format.name(), container.extension())
}
