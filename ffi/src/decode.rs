//! Decoding texels and regions of a material (`nmat_decode_*`, `nmat_required_size`).

use crate::material::{handle, material, nmat_material};
use crate::pointers::{arg_mut, slice, slice_mut};
use crate::status::nmat_status::*;
use crate::status::{bad, fail, guard, nmat_status, set_last_error};
use nmat_core::{ChannelMask, Material, TexelAt};

/// Which decoder computes the values.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum nmat_mode {
    /// Integer-exact (W8A16): bit-identical on every platform and on the GPU runtime.
    NMAT_MODE_INTEGER = 0,
    /// The float reference decoder (the int8 network dequantized, f32 arithmetic).
    NMAT_MODE_FLOAT = 1,
}

/// The channels of `channel_mask` and how many values a texel of them is.
pub(crate) fn mask(
    m: &Material<'_>,
    channel_mask: u32,
) -> Result<(ChannelMask, usize), nmat_status> {
    let mask = u16::try_from(channel_mask).map_err(|_| bad("channel mask beyond 16 channels"))?;
    let n = m.required_len(ChannelMask(mask)).map_err(fail)?;
    Ok((ChannelMask(mask), n))
}

/// Decodes texel (x, y) of `mip` for the channels in `channel_mask` (bit c = channel c;
/// 0xFFFF = all) with decoder `mode` (an `nmat_mode`) into `out` (values in each channel's
/// range, packed in channel order).
/// Coordinates outside the mip wrap or clamp by the material's address mode; a mip beyond the
/// chain is `NMAT_BAD_ARGUMENT`.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_texel(
    m: *const nmat_material,
    x: i64,
    y: i64,
    mip: u32,
    channel_mask: u32,
    mode: u32,
    out: *mut f32,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let out = slice_mut(out, out_len)?;
        let (mask, n) = mask(m, channel_mask)?;
        if mip >= m.mip_count() {
            return Err(bad("mip beyond the chain"));
        }
        match decode_mode(mode)? {
            nmat_mode::NMAT_MODE_FLOAT => {
                decoder.decode_texel(m, x, y, mip, mask, out).map(|_| ()).map_err(fail)
            }
            nmat_mode::NMAT_MODE_INTEGER => {
                let mut codes = [0u8; 16];
                decoder.decode_texel_u8(m, x, y, mip, mask, &mut codes).map_err(fail)?;
                let channels = selected(m, mask);
                if out.len() < n {
                    return Err(NMAT_BUFFER_TOO_SMALL);
                }
                for ((o, c), ch) in out.iter_mut().zip(codes).zip(channels) {
                    let u = f32::from(c) / 255.0;
                    *o = ch.range_min * (1.0 - u) + ch.range_max * u;
                }
                Ok(())
            }
        }
    })
}

/// A C enum arrives as an integer that may hold anything: converted here, never transmuted.
pub(crate) fn decode_mode(mode: u32) -> Result<nmat_mode, nmat_status> {
    match mode {
        0 => Ok(nmat_mode::NMAT_MODE_INTEGER),
        1 => Ok(nmat_mode::NMAT_MODE_FLOAT),
        _ => Err(bad("mode is not an nmat_mode")),
    }
}

pub(crate) fn selected<'m>(
    m: &'m Material<'_>,
    mask: ChannelMask,
) -> impl Iterator<Item = &'m nmat_core::Channel<'m>> {
    let bits = mask.resolve(m.channel_count()).unwrap_or(0);
    m.channels().iter().enumerate().filter(move |(i, _)| bits & (1 << i) != 0).map(|(_, c)| c)
}

/// Integer-exact decode of one texel to 8-bit codes (0 = range_min, 255 = range_max).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_texel_u8(
    m: *const nmat_material,
    x: i64,
    y: i64,
    mip: u32,
    channel_mask: u32,
    out: *mut u8,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let out = slice_mut(out, out_len)?;
        let (mask, _) = mask(m, channel_mask)?;
        if mip >= m.mip_count() {
            return Err(bad("mip beyond the chain"));
        }
        decoder.decode_texel_u8(m, x, y, mip, mask, out).map(|_| ()).map_err(fail)
    })
}

/// A texel's address for `nmat_decode_texels_u8`: column, row and mip. Coordinates outside the
/// mip wrap or clamp by the material's address mode; a mip beyond the chain is refused.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct nmat_texel_at {
    /// Column.
    pub x: i64,
    /// Row.
    pub y: i64,
    /// Mip level (0 = full size).
    pub mip: u32,
}

/// Integer-exact decode of `count` scattered texels to 8-bit codes: texel i of `texels` into
/// `out[i·n ..]`, n the channels of `channel_mask`, each texel's codes those of
/// `nmat_decode_texel_u8`. For random access to many texels this is faster than one call each:
/// a few texels at a time have their latents fetched together and go through the network
/// together. `out_len` must be at least count · n (`NMAT_BUFFER_TOO_SMALL` otherwise); a texel
/// whose mip is beyond the chain is `NMAT_BAD_ARGUMENT` (its index is in the error text) and
/// nothing is written.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_texels_u8(
    m: *const nmat_material,
    texels: *const nmat_texel_at,
    count: usize,
    channel_mask: u32,
    out: *mut u8,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let texels = slice(texels, count)?;
        let out = slice_mut(out, out_len)?;
        let (mask, n) = mask(m, channel_mask)?;
        // `slice` bounded count · 24 bytes, so count · n (n ≤ 16) does not overflow.
        let needed = count * n;
        if out_len < needed {
            set_last_error(format!(
                "{count} texels of {n} channels need {needed} bytes, the buffer has {out_len}"
            ));
            return Err(NMAT_BUFFER_TOO_SMALL);
        }
        if let Some(i) = texels.iter().position(|t| t.mip >= m.mip_count()) {
            let chain = m.mip_count();
            return Err(bad(&format!(
                "texel {i}'s mip {} beyond the chain of {chain}",
                texels[i].mip
            )));
        }
        // The core's address type, a few at a time (no allocation).
        let mut at = [TexelAt::default(); 64];
        for (chunk, codes) in texels.chunks(at.len()).zip(out.chunks_mut(at.len() * n)) {
            for (a, t) in at.iter_mut().zip(chunk) {
                *a = TexelAt { x: t.x, y: t.y, mip: t.mip };
            }
            decoder.decode_texels_u8(m, &at[..chunk.len()], mask, codes).map_err(fail)?;
        }
        Ok(())
    })
}

/// The buffer a region decode needs: `*row_bytes` = width · channels · bytes_per_value (the
/// smallest valid row pitch) and `*total_bytes` = row_pitch · (height − 1) + row_bytes for the
/// given `row_pitch` (0 = tightly packed). Reports `NMAT_SIZE_OVERFLOW` instead of wrapping.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_required_size(
    m: *const nmat_material,
    width: u32,
    height: u32,
    channel_mask: u32,
    bytes_per_value: usize,
    row_pitch: usize,
    row_bytes: *mut usize,
    total_bytes: *mut usize,
) -> nmat_status {
    guard(|| {
        let m = material(m)?;
        let (row_out, total_out) = (arg_mut(row_bytes)?, arg_mut(total_bytes)?);
        let (_, n) = mask(m, channel_mask)?;
        let (row, total) = region_size(width, height, n, bytes_per_value, row_pitch)?;
        (*row_out, *total_out) = (row, total);
        Ok(())
    })
}

pub(crate) fn region_size(
    width: u32,
    height: u32,
    channels: usize,
    bytes: usize,
    pitch: usize,
) -> Result<(usize, usize), nmat_status> {
    let overflow = || {
        set_last_error("the region's size overflows size_t".into());
        NMAT_SIZE_OVERFLOW
    };
    let row = (width as usize)
        .checked_mul(channels)
        .and_then(|v| v.checked_mul(bytes))
        .ok_or_else(overflow)?;
    let pitch = if pitch == 0 { row } else { pitch };
    if pitch < row {
        set_last_error(format!("row pitch {pitch} is below the row size {row}"));
        return Err(NMAT_BUFFER_TOO_SMALL);
    }
    let total = if height == 0 {
        0
    } else {
        pitch
            .checked_mul(height as usize - 1)
            .and_then(|v| v.checked_add(row))
            .ok_or_else(overflow)?
    };
    Ok((row, total))
}

/// Checks a region against the mip and the buffer; returns (mask, channels, pitch).
pub(crate) fn region_checks(
    m: &Material<'_>,
    mip: u32,
    rect: (u32, u32, u32, u32),
    channel_mask: u32,
    bytes: usize,
    pitch: usize,
    out_len_bytes: usize,
) -> Result<(ChannelMask, usize, usize), nmat_status> {
    let (x0, y0, w, h) = rect;
    if mip >= m.mip_count() {
        return Err(bad("mip beyond the chain"));
    }
    let (mw, mh) = m.mip_size(mip);
    if x0.checked_add(w).is_none_or(|e| e > mw) || y0.checked_add(h).is_none_or(|e| e > mh) {
        return Err(bad("region outside the mip"));
    }
    let (mask, n) = mask(m, channel_mask)?;
    let (row, total) = region_size(w, h, n, bytes, pitch)?;
    if out_len_bytes < total {
        set_last_error(format!("the region needs {total} bytes, the buffer has {out_len_bytes}"));
        return Err(NMAT_BUFFER_TOO_SMALL);
    }
    Ok((mask, n, if pitch == 0 { row } else { pitch }))
}

/// Integer-exact decode of the rectangle (x0, y0, width, height) of `mip` into `out`: rows of
/// `width · channels` codes, `row_pitch` bytes apart (0 = packed), `out_len` bytes in all.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_region_u8(
    m: *const nmat_material,
    mip: u32,
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
    channel_mask: u32,
    out: *mut u8,
    row_pitch: usize,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let out = slice_mut(out, out_len)?;
        let (mask, _, pitch) =
            region_checks(m, mip, (x0, y0, width, height), channel_mask, 1, row_pitch, out_len)?;
        decoder
            .decode_region_u8(m, mip, (x0, y0, width, height), mask, out, pitch)
            .map_err(fail)?;
        Ok(())
    })
}

/// Float decode of a rectangle (values in channel ranges): like `nmat_decode_region_u8` with
/// `float` values; `row_pitch` and `out_len` count **bytes**.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_region_f32(
    m: *const nmat_material,
    mip: u32,
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
    channel_mask: u32,
    mode: u32,
    out: *mut f32,
    row_pitch: usize,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (mm, decoder) = (h.material(), &h.decoder);
        if !row_pitch.is_multiple_of(4) {
            return Err(bad("row pitch of a float region must be a multiple of 4 bytes"));
        }
        let mode = decode_mode(mode)?;
        let out = slice_mut(out, out_len / 4)?;
        let (mask, n, pitch) =
            region_checks(mm, mip, (x0, y0, width, height), channel_mask, 4, row_pitch, out_len)?;
        let ranges: Vec<(f32, f32)> =
            selected(mm, mask).map(|c| (c.range_min, c.range_max)).collect();
        let row_len = width as usize * n;
        let mut codes = vec![0u8; if mode == nmat_mode::NMAT_MODE_INTEGER { row_len } else { 0 }];
        for y in 0..height as usize {
            let start = y * pitch / 4;
            let row = out.get_mut(start..start + row_len).ok_or(NMAT_BUFFER_TOO_SMALL)?;
            let (x, ty) = (i64::from(x0), i64::from(y0) + y as i64);
            let w = width as usize;
            match mode {
                nmat_mode::NMAT_MODE_FLOAT => {
                    decoder.decode_span_f32(mm, x, ty, mip, w, mask, row).map_err(fail)?;
                }
                nmat_mode::NMAT_MODE_INTEGER => {
                    decoder.decode_span_u8(mm, x, ty, mip, w, mask, &mut codes).map_err(fail)?;
                    for (i, (o, &c)) in row.iter_mut().zip(&codes).enumerate() {
                        let (lo, hi) = ranges.get(i % n).copied().unwrap_or((0.0, 1.0));
                        let u = f32::from(c) / 255.0;
                        *o = lo * (1.0 - u) + hi * u;
                    }
                }
            }
        }
        Ok(())
    })
}
