//! BC (GPU block-compressed) textures from a material: formats, layouts and transcoding
//! (`nmat_bc_*`, `nmat_transcode_region`).

use crate::boundary::boundary;
use crate::material::{handle, material, nmat_material};
use crate::pointers::{arg, arg_mut, slice_mut};
use crate::status::nmat_status::*;
use crate::status::{bad, fail, guard, nmat_status, set_last_error};

/// A BC (GPU block-compressed) format of `nmat_bc_texture`; the numbers are stable.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum nmat_bc_format {
    /// RGB, 8 bytes per 4×4 block (`DXGI_FORMAT_BC1_UNORM[_SRGB]`); never transparent.
    NMAT_BC1 = 1,
    /// One channel, 8 bytes per block (`BC4_UNORM`).
    NMAT_BC4 = 4,
    /// Two channels, 16 bytes per block (`BC5_UNORM`).
    NMAT_BC5 = 5,
    /// RGB in BC7, alpha 255, 16 bytes per block (`BC7_UNORM[_SRGB]`).
    NMAT_BC7_RGB = 7,
    /// RGBA in BC7, 16 bytes per block.
    NMAT_BC7_RGBA = 8,
}

impl nmat_bc_format {
    const ALL: [nmat_bc_format; 5] = [
        nmat_bc_format::NMAT_BC1,
        nmat_bc_format::NMAT_BC4,
        nmat_bc_format::NMAT_BC5,
        nmat_bc_format::NMAT_BC7_RGB,
        nmat_bc_format::NMAT_BC7_RGBA,
    ];

    fn core(self) -> nmat_core::bc::BcFormat {
        use nmat_core::bc::BcFormat;
        match self {
            nmat_bc_format::NMAT_BC1 => BcFormat::Bc1,
            nmat_bc_format::NMAT_BC4 => BcFormat::Bc4,
            nmat_bc_format::NMAT_BC5 => BcFormat::Bc5,
            nmat_bc_format::NMAT_BC7_RGB => BcFormat::Bc7Rgb,
            nmat_bc_format::NMAT_BC7_RGBA => BcFormat::Bc7Rgba,
        }
    }

    fn from_u32(v: u32) -> Option<nmat_bc_format> {
        nmat_bc_format::ALL.into_iter().find(|f| *f as u32 == v)
    }

    fn of(f: nmat_core::bc::BcFormat) -> nmat_bc_format {
        nmat_bc_format::ALL.into_iter().find(|c| c.core() == f).unwrap_or(nmat_bc_format::NMAT_BC1)
    }
}

/// One BC texture made from a material: its format (an `nmat_bc_format`), the material channels
/// of its R, G, B, A components (the first 1, 2, 3 or 4 are used, by format; repeats allowed),
/// and whether to sample it as sRGB (1; BC1 and BC7 only).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct nmat_bc_texture {
    pub format: u32,
    pub channels: [u8; 4],
    pub srgb: u32,
}

/// Bytes per 4×4 block of `format` (an `nmat_bc_format`): 8 or 16; 0 for an unknown format.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_bc_block_bytes(format: u32) -> usize {
    boundary(|| nmat_bc_format::from_u32(format).map_or(0, |f| f.core().block_bytes()))
}

/// The BC textures for the material's maps: with `format` 0, chosen from each map's meaning
/// (albedo → BC1 sRGB, normal → BC5 of X and Y, one channel → BC4, two → BC5, a fourth component
/// → its own BC4); with an `nmat_bc_format`, every map in that format (BC7: RGBA for maps of four
/// channels). Sets `*count` (at most 16) and writes that many textures to `out`; with `out` NULL
/// and `capacity` 0 it only sets the count. `NMAT_BUFFER_TOO_SMALL` (with `*count` set, nothing
/// written) when `capacity` is below the count.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_bc_layout(
    m: *const nmat_material,
    format: u32,
    out: *mut nmat_bc_texture,
    capacity: usize,
    count: *mut usize,
) -> nmat_status {
    guard(|| {
        let m = material(m)?;
        let count = arg_mut(count)?;
        let chosen = match format {
            0 => None,
            f => Some(nmat_bc_format::from_u32(f).ok_or_else(|| bad("unknown BC format"))?),
        };
        let layout = nmat_core::bc::layout_with(m, |_| chosen.map(nmat_bc_format::core));
        *count = layout.len();
        if out.is_null() && capacity == 0 {
            return Ok(());
        }
        if capacity < layout.len() {
            set_last_error(format!(
                "the layout has {} textures, the buffer holds {capacity}",
                layout.len()
            ));
            return Err(NMAT_BUFFER_TOO_SMALL);
        }
        if layout.is_empty() {
            return Ok(());
        }
        let out = slice_mut(out, capacity)?;
        for (o, t) in out.iter_mut().zip(&layout) {
            *o = nmat_bc_texture {
                format: nmat_bc_format::of(t.format) as u32,
                channels: t.channels,
                srgb: u32::from(t.srgb),
            };
        }
        Ok(())
    })
}

/// Decodes the blocks (block_x, block_y, blocks_wide, blocks_high) of `mip` — in 4×4 blocks; a
/// mip of w × h texels has ⌈w/4⌉ × ⌈h/4⌉ — with the integer decoder and encodes them as BC
/// blocks of `texture` into `out`: block row r at `out + r · row_pitch` (0 = packed), `out_len`
/// bytes in all. Pixels past the mip's edge do not influence the blocks. The bytes depend only on
/// the material and the arguments (not on the CPU, the kernel or how a mip is split into
/// regions, e.g. across threads). Nothing is written on error.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_transcode_region(
    m: *const nmat_material,
    texture: *const nmat_bc_texture,
    mip: u32,
    block_x: u32,
    block_y: u32,
    blocks_wide: u32,
    blocks_high: u32,
    out: *mut u8,
    row_pitch: usize,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let t = arg(texture)?;
        let format = nmat_bc_format::from_u32(t.format).ok_or_else(|| bad("unknown BC format"))?;
        let texture = nmat_core::bc::BcTexture {
            format: format.core(),
            channels: t.channels,
            srgb: t.srgb != 0,
        };
        let out = slice_mut(out, out_len)?;
        let row =
            (blocks_wide as usize).checked_mul(format.core().block_bytes()).ok_or_else(|| {
                set_last_error("the region's size overflows size_t".into());
                NMAT_SIZE_OVERFLOW
            })?;
        let pitch = if row_pitch == 0 { row } else { row_pitch };
        let region = nmat_core::BlockRegion {
            x: block_x,
            y: block_y,
            width: blocks_wide,
            height: blocks_high,
        };
        h.decoder.transcode_blocks(h.material(), &texture, mip, region, out, pitch).map_err(fail)
    })
}
