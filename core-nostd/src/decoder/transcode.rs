//! Decoding straight into BC blocks ([`Decoder::transcode_blocks`]): a region of whole 4×4 blocks
//! of a mip, decoded row band by row band into a small stack buffer and encoded block by block
//! with [`crate::bc`], so nothing the size of a mip is ever materialized.

use super::Decoder;
use crate::bc::{self, BLOCK_PIXELS, BcTexture};
use crate::decode::ChannelMask;
use crate::error::{Argument, Error};
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

/// Blocks encoded per decode pass: 64 texels per row, 4 rows.
const CHUNK: usize = 16;

impl Decoder {
    /// Decodes `region` of mip `mip` with the integer decoder (8-bit codes) and encodes it as BC
    /// blocks of `texture`: block row `r` of the region starts at `out[r · row_pitch]`, its blocks
    /// left to right, `texture.format.block_bytes()` bytes each. Pixels past the mip's right or
    /// bottom edge are not decoded and do not influence the blocks (as GPUs never show them). The
    /// bytes depend only on the material and the arguments — not on the kernel, the CPU or how
    /// a caller splits a mip into regions (e.g. block rows across threads).
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
        self.check(material)?;
        if mip >= material.mip_count() {
            return Err(bad(Argument::Mip, mip, material.mip_count().saturating_sub(1)));
        }
        let mask = texture.channel_list().iter().fold(0u16, |m, &c| m | (1 << (c & 15)));
        let too_high = texture.channel_list().iter().find(|&&c| usize::from(c) >= 16);
        if let Some(&c) = too_high {
            return Err(bad(Argument::Channels, c, material.channel_count().saturating_sub(1)));
        }
        let rows = material.resolve_channels(ChannelMask(mask))?;
        let (w, h) = material.mip_size(mip);
        let all = BlockRegion::mip(material, mip);
        let x_end = u64::from(region.x) + u64::from(region.width);
        let y_end = u64::from(region.y) + u64::from(region.height);
        if x_end > u64::from(all.width) {
            return Err(bad(Argument::Region, x_end, all.width));
        }
        if y_end > u64::from(all.height) {
            return Err(bad(Argument::Region, y_end, all.height));
        }
        let block_bytes = texture.format.block_bytes();
        let row_bytes = region.width as usize * block_bytes;
        if row_pitch < row_bytes {
            return Err(bad(Argument::RowPitch, row_pitch, row_bytes));
        }
        let needed = match region.height {
            0 => 0,
            n => (n as usize - 1).saturating_mul(row_pitch).saturating_add(row_bytes),
        };
        if out.len() < needed {
            return Err(bad(Argument::Output, out.len(), needed));
        }
        let n = rows.count_ones() as usize;
        // Where each component of the texture sits among the decoded channels (ascending order).
        let slot = |c: u8| (rows & ((1u16 << c) - 1)).count_ones() as usize;
        let picks: [usize; 4] =
            core::array::from_fn(|k| texture.channel_list().get(k).map_or(0, |&c| slot(c)));
        // A constant channel is not decoded: its code comes from its value.
        let constants: [Option<u8>; 4] = core::array::from_fn(|k| {
            let c = texture.channel_list().get(k)?;
            material.channels().get(usize::from(*c))?.constant_code()
        });
        let mut band = [0u8; 4 * 4 * CHUNK * 4];
        for (r, by) in (region.y..y_end as u32).enumerate() {
            let row_out = out.get_mut(r * row_pitch..).unwrap_or(&mut []);
            let mut bx = region.x;
            while u64::from(bx) < x_end {
                let blocks = (x_end - u64::from(bx)).min(CHUNK as u64) as usize;
                // Texels of this chunk that exist in each row (the rest stay 0 and are masked).
                let texels = (w.saturating_sub(4 * bx) as usize).min(4 * blocks);
                for y in 0..4u32 {
                    let row = band.get_mut(y as usize * 4 * CHUNK * n..).unwrap_or(&mut []);
                    if 4 * by + y < h {
                        // Checked above: the material, the channels, and a band row holds
                        // 4·CHUNK texels of n channels.
                        let at = (i64::from(4 * bx), i64::from(4 * by + y), mip);
                        self.span_codes(material, at, texels, (rows, n), row, 255, |c| c as u8);
                    }
                }
                for k in 0..blocks {
                    let (cx, cy) = (bx + k as u32, by);
                    let valid = bc::valid_mask(cx, cy, w, h);
                    let at = |i: usize, comp: usize| -> u8 {
                        if let Some(&Some(code)) = constants.get(comp) {
                            return code;
                        }
                        let (x, y) = (4 * k + i % 4, i / 4);
                        let pick = picks.get(comp).copied().unwrap_or(0);
                        band.get((y * 4 * CHUNK + x) * n + pick).copied().unwrap_or(0)
                    };
                    let px: [[u8; 4]; BLOCK_PIXELS] =
                        core::array::from_fn(|i| [at(i, 0), at(i, 1), at(i, 2), at(i, 3)]);
                    let start = (cx - region.x) as usize * block_bytes;
                    let dst = row_out.get_mut(start..).unwrap_or(&mut []);
                    bc::encode_block(texture.format, &px, valid, dst);
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
