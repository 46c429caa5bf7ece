//! Decoding straight into BC blocks ([`Decoder::transcode_blocks`]): a region of whole 4×4 blocks
//! of a mip, decoded row band by row band into a small stack buffer and encoded block by block
//! with [`crate::bc`], so nothing the size of a mip is ever materialized.

use super::Decoder;
use crate::bc::{self, BLOCK_PIXELS, BcTexture};
use crate::decode::ChannelMask;
use crate::error::{Argument, Error};
use crate::limits::MAX_CHANNELS;
use crate::material::Material;

/// A rectangle of whole 4×4 blocks of a mip, in blocks: the blocks `x .. x + width` of block rows
/// `y .. y + height`. [`BlockRegion::mip`] is all of a mip.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BlockRegion {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl BlockRegion {
    /// Every block of mip `mip` of `material` (a mip of w × h texels has ⌈w/4⌉ × ⌈h/4⌉ blocks;
    /// an empty region for a mip the material does not have).
    pub fn mip(material: &Material<'_>, mip: u32) -> BlockRegion {
        let (w, h) = if mip < material.mip_count() { material.mip_size(mip) } else { (0, 0) };
        BlockRegion { x: 0, y: 0, width: w.div_ceil(4), height: h.div_ceil(4) }
    }
}

/// Blocks per decode pass: 64 texels per row, 4 rows.
const CHUNK: usize = 16;
/// Bytes of the band of decoded codes on the stack: 4 rows of 4·CHUNK texels of up to every
/// channel.
const BAND: usize = 4 * 4 * CHUNK * MAX_CHANNELS;

/// One BC texture of [`Decoder::transcode_textures`] and where its blocks go: block row `r` of
/// the region starts at `out[r · row_pitch]`, its blocks left to right.
#[derive(Debug)]
pub struct BcTarget<'a> {
    pub texture: BcTexture,
    pub out: &'a mut [u8],
    pub row_pitch: usize,
}

impl Decoder {
    /// Decodes `region` of mip `mip` with the integer decoder (8-bit codes) and encodes it as BC
    /// blocks of `texture`: block row `r` of the region starts at `out[r · row_pitch]`, its blocks
    /// left to right, `texture.format.block_bytes()` bytes each. Pixels past the mip's right or
    /// bottom edge are not decoded and do not influence the blocks (as GPUs never show them). The
    /// bytes depend only on the material and the arguments — not on the kernel, the CPU or how
    /// a caller splits a mip into regions (e.g. block rows across threads).
    /// [`Decoder::transcode_textures`] writes several textures of the same region in one pass
    /// of the network (the same bytes, faster).
    ///
    /// Errors: another material than the decoder's ([`Argument::Material`]), a mip the material
    /// does not have ([`Argument::Mip`]), a channel it does not have ([`Argument::Channels`]), a
    /// region past the mip's blocks ([`Argument::Region`]), a row pitch shorter than a block row
    /// ([`Argument::RowPitch`]), or `out` too short ([`Argument::Output`]).
    #[allow(clippy::too_many_arguments)] // a material, what, where, and the output with its pitch
    pub fn transcode_blocks(
        &self,
        material: &Material<'_>,
        texture: &BcTexture,
        mip: u32,
        region: BlockRegion,
        out: &mut [u8],
        row_pitch: usize,
    ) -> Result<(), Error> {
        let mut target = [BcTarget { texture: *texture, out, row_pitch }];
        self.transcode_textures(material, mip, region, &mut target)
    }

    /// [`Decoder::transcode_blocks`] for several textures of the same region at once: each block
    /// row is decoded once for the channels of all `targets` (the network's hidden layers run once
    /// instead of once per texture) and encoded into each target. Every target's bytes equal
    /// `transcode_blocks` of its texture alone. All targets are checked before anything is
    /// written; the errors are those of `transcode_blocks`.
    pub fn transcode_textures(
        &self,
        material: &Material<'_>,
        mip: u32,
        region: BlockRegion,
        targets: &mut [BcTarget<'_>],
    ) -> Result<(), Error> {
        let bound = self.bind(material)?;
        if mip >= material.mip_count() {
            return Err(bad(Argument::Mip, mip, material.mip_count().saturating_sub(1)));
        }
        let all = BlockRegion::mip(material, mip);
        let x_end = u64::from(region.x) + u64::from(region.width);
        let y_end = u64::from(region.y) + u64::from(region.height);
        if x_end > u64::from(all.width) {
            return Err(bad(Argument::Region, x_end, all.width));
        }
        if y_end > u64::from(all.height) {
            return Err(bad(Argument::Region, y_end, all.height));
        }
        let mut mask = 0u16;
        for target in targets.iter() {
            let list = target.texture.channel_list();
            if let Some(&c) = list.iter().find(|&&c| usize::from(c) >= 16) {
                return Err(bad(Argument::Channels, c, material.channel_count().saturating_sub(1)));
            }
            let own = list.iter().fold(0u16, |m, &c| m | (1 << c));
            material.resolve_channels(ChannelMask(own))?;
            mask |= own;
            let row_bytes = region.width as usize * target.texture.format.block_bytes();
            if target.row_pitch < row_bytes {
                return Err(bad(Argument::RowPitch, target.row_pitch, row_bytes));
            }
            let needed = match region.height {
                0 => 0,
                n => (n as usize - 1).saturating_mul(target.row_pitch).saturating_add(row_bytes),
            };
            if target.out.len() < needed {
                return Err(bad(Argument::Output, target.out.len(), needed));
            }
        }
        if targets.is_empty() {
            return Ok(());
        }
        let rows = material.resolve_channels(ChannelMask(mask))?;
        let (w, h) = material.mip_size(mip);
        let n = rows.count_ones() as usize;
        let band_row = 4 * CHUNK * n;
        let mut band = [0u8; BAND];
        for (r, by) in (region.y..y_end as u32).enumerate() {
            let mut bx = region.x;
            while u64::from(bx) < x_end {
                let blocks = (x_end - u64::from(bx)).min(CHUNK as u64) as usize;
                // Texels of this chunk that exist in each row (the rest stay 0 and are masked).
                let texels = (w.saturating_sub(4 * bx) as usize).min(4 * blocks);
                for y in 0..4u32 {
                    let row = band.get_mut(y as usize * band_row..).unwrap_or(&mut []);
                    if 4 * by + y < h {
                        // Checked above: the material, the channels, and a band row holds
                        // 4·CHUNK texels of n channels.
                        let at = (i64::from(4 * bx), i64::from(4 * by + y), mip);
                        let span = (rows, n);
                        self.span_codes((material, bound), at, texels, span, row, 255, |c| c as u8);
                    }
                }
                for target in targets.iter_mut() {
                    let texture = &target.texture;
                    // Where each component sits among the decoded channels (ascending order),
                    // or its code if the channel is constant (not decoded: its value's code).
                    let slot = |c: u8| (rows & ((1u16 << c) - 1)).count_ones() as usize;
                    let list = texture.channel_list();
                    let picks: [usize; 4] =
                        core::array::from_fn(|k| list.get(k).map_or(0, |&c| slot(c)));
                    let constants: [Option<u8>; 4] = core::array::from_fn(|k| {
                        material.channels().get(usize::from(*list.get(k)?))?.constant_code()
                    });
                    let block_bytes = texture.format.block_bytes();
                    let row_out = target.out.get_mut(r * target.row_pitch..).unwrap_or(&mut []);
                    for k in 0..blocks {
                        let (cx, cy) = (bx + k as u32, by);
                        let valid = bc::valid_mask(cx, cy, w, h);
                        let at = |i: usize, comp: usize| -> u8 {
                            if let Some(&Some(code)) = constants.get(comp) {
                                return code;
                            }
                            let (x, y) = (4 * k + i % 4, i / 4);
                            let pick = picks.get(comp).copied().unwrap_or(0);
                            band.get(y * band_row + x * n + pick).copied().unwrap_or(0)
                        };
                        let px: [[u8; 4]; BLOCK_PIXELS] =
                            core::array::from_fn(|i| [at(i, 0), at(i, 1), at(i, 2), at(i, 3)]);
                        let start = (cx - region.x) as usize * block_bytes;
                        let dst = row_out.get_mut(start..).unwrap_or(&mut []);
                        bc::encode_block(texture.format, &px, valid, dst);
                    }
                }
                bx += blocks as u32;
            }
        }
        Ok(())
    }
}

fn bad(argument: Argument, value: impl TryInto<u64>, limit: impl TryInto<u64>) -> Error {
    Error::BadArgument {
        argument,
        value: value.try_into().unwrap_or(u64::MAX),
        limit: limit.try_into().unwrap_or(u64::MAX),
    }
}
