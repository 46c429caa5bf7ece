//! Filtered sampling of a material (`nmat_sample`), and the lookup the tile cache shares.

use crate::decode::{decode_mode, mask, nmat_mode};
use crate::material::{handle, nmat_material};
use crate::pointers::{check_ptr, slice, slice_mut};
use crate::status::nmat_status::*;
use crate::status::{bad, fail, guard, nmat_status};
use nmat_core::{ChannelMask, Filter, Precision, SampleRequest};

/// Texture filter of `nmat_sample`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum nmat_filter {
    NMAT_FILTER_NEAREST = 0,
    NMAT_FILTER_BILINEAR = 1,
    NMAT_FILTER_TRILINEAR = 2,
    /// One decode per sample, the texel drawn with the caller's random numbers.
    NMAT_FILTER_STOCHASTIC = 3,
}

/// Filtered sample at normalized (u, v) and fractional `lod` with `filter` (an `nmat_filter`)
/// and decoder `mode` (an `nmat_mode`). `random` points to 3 uniform
/// numbers in [0, 1) for `NMAT_FILTER_STOCHASTIC` (may be NULL for the other filters).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_sample(
    m: *const nmat_material,
    u: f32,
    v: f32,
    lod: f32,
    filter: u32,
    mode: u32,
    random: *const f32,
    channel_mask: u32,
    out: *mut f32,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let out = slice_mut(out, out_len)?;
        let (channels, _) = mask(m, channel_mask)?;
        let precision = match decode_mode(mode)? {
            nmat_mode::NMAT_MODE_INTEGER => Precision::Integer,
            nmat_mode::NMAT_MODE_FLOAT => Precision::Float,
        };
        let req = SampleRequest { precision, channels, ..request(u, v, lod, filter, random)? };
        decoder.sample(m, &req, out).map(|_| ()).map_err(fail)
    })
}

/// The lookup of `nmat_sample` and `nmat_cache_mark`/`_resolve` (integer precision, every
/// channel; callers set the two): the filter checked, `random` read (NULL only when the filter
/// does not use it).
pub(crate) fn request(
    u: f32,
    v: f32,
    lod: f32,
    filter: u32,
    random: *const f32,
) -> Result<SampleRequest, nmat_status> {
    let filter = match filter {
        0 => Filter::Nearest,
        1 => Filter::Bilinear,
        2 => Filter::Trilinear,
        3 => Filter::Stochastic,
        _ => return Err(bad("filter is not an nmat_filter")),
    };
    let random = if random.is_null() {
        if filter == Filter::Stochastic {
            return Err(check_ptr(random, "pointer argument").err().unwrap_or(NMAT_NULL_ARGUMENT));
        }
        [0.0; 3]
    } else {
        let r = slice(random, 3)?;
        [r[0], r[1], r[2]]
    };
    Ok(SampleRequest {
        u,
        v,
        lod,
        filter,
        precision: Precision::Integer,
        random,
        channels: ChannelMask::ALL,
    })
}
