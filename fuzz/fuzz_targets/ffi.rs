//! Drives the C API the way a C caller could: open (copying and borrowing) fuzzer bytes with a
//! valid checksum patched in (zlib's CRC-32: the parser must agree), then every query and decode
//! with fuzzer-chosen arguments, NULL pointers and short buffers included. Every call must return
//! a status, never crash.
#![no_main]
use arbitrary::{Arbitrary, Unstructured};
use libfuzzer_sys::fuzz_target;
use nmat::*;
use std::ptr::{null, null_mut};

#[derive(Arbitrary, Debug)]
struct Call {
    which: u8,
    a: i64,
    b: i64,
    c: u32,
    mask: u32,
    mode: u32,
    len: u8,
    rect: [u16; 4],
    pitch: u16,
    null: bool,
}

fuzz_target!(|data: &[u8]| {
    // As in `decode`: the file up to its declared length, the calls from the bytes after it.
    let declared = data.get(12..16).map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
    let split = if (32..=data.len()).contains(&declared) { declared } else { data.len() };
    let (file, controls) = data.split_at(split);
    let mut u = Unstructured::new(controls);
    // Eight calls at most: a region decode costs a network evaluation per texel.
    let mut calls: Vec<Call> = (0..8).map_while(|_| Call::arbitrary(&mut u).ok()).collect();
    if calls.is_empty() {
        calls = (0..8u8)
            .map(|which| Call { which, a: 3, b: -2, c: 1, mask: 0xFFFF, mode: 1, len: 16, rect: [0, 0, 4, 4], pitch: 0, null: false })
            .collect();
    }
    let borrowed = controls.first().is_some_and(|b| b & 1 == 1);
    let mut file = file.to_vec();
    // The checksum (FORMAT.md §2: CRC-32 of the file with its 4 checksum bytes as zero) from
    // zlib's CRC-32 in crc32fast: an independent implementation, and one that costs the fuzzer
    // a few instrumented steps per 64 bytes instead of several per 8.
    let patched = file.len() >= 24;
    if patched {
        let mut crc = crc32fast::Hasher::new();
        crc.update(&file[..20]);
        crc.update(&[0; 4]);
        crc.update(&file[24..]);
        file[20..24].copy_from_slice(&crc.finalize().to_le_bytes());
    }
    let mut m: *mut nmat_material = null_mut();
    let status = if borrowed {
        nmat_material_open_borrowed(file.as_ptr(), file.len(), &mut m)
    } else {
        nmat_material_open(file.as_ptr(), file.len(), &mut m)
    };
    assert_eq!(status == nmat_status::NMAT_OK, !m.is_null());
    assert!(!patched || status != nmat_status::NMAT_CHECKSUM_MISMATCH, "the core's CRC-32 differs from zlib's");
    let handle: *const nmat_material = if m.is_null() { null() } else { m };
    // Output buffers smaller than the largest region a call asks for (8 × 8 texels of 16 bytes;
    // 4 × 4 of 16 floats), so that a short buffer stays reachable without a huge pitch. Regions
    // stay small: each texel costs a network evaluation.
    let mut floats = vec![0f32; 128];
    let mut bytes = vec![0u8; 512];
    for call in &calls {
        let h = if call.null { null() } else { handle };
        let len = usize::from(call.len);
        let [x0, y0, w, hh] = call.rect.map(u32::from);
        let _ = match call.which % 8 {
            0 => nmat_decode_texel(h, call.a, call.b, call.c, call.mask, call.mode, floats.as_mut_ptr(), len.min(floats.len())),
            1 => nmat_decode_texel_u8(h, call.a, call.b, call.c, call.mask, bytes.as_mut_ptr(), len.min(bytes.len())),
            2 => nmat_sample(h, call.a as f32 * 1e-3, call.b as f32 * 1e-3, call.c as f32 * 1e-2, call.mode % 5, call.mode / 5 % 3, floats.as_ptr(), call.mask, floats.as_mut_ptr().wrapping_add(3), len.min(floats.len() - 3)),
            3 => nmat_decode_region_u8(h, call.c, x0 % 64, y0 % 64, w % 9, hh % 9, call.mask, bytes.as_mut_ptr(), usize::from(call.pitch), bytes.len()),
            4 => nmat_decode_region_f32(h, call.c, x0 % 32, y0 % 32, w % 5, hh % 5, call.mask, call.mode, floats.as_mut_ptr(), usize::from(call.pitch), floats.len() * 4),
            5 => {
                let (mut row, mut total) = (0usize, 0usize);
                nmat_required_size(h, x0 << 16 | w, y0 << 16 | hh, call.mask, call.a as usize, usize::from(call.pitch), &mut row, &mut total)
            }
            // Up to 8 scattered texels (each a network evaluation), their addresses and mips from
            // the call, some far outside the mip or past the chain.
            6 => {
                let texels: Vec<nmat_texel_at> = (0..i64::from(call.len % 9))
                    .map(|i| nmat_texel_at { x: call.a.wrapping_add(i * 7), y: call.b.wrapping_sub(i), mip: call.c >> (i % 4) })
                    .collect();
                let at = if texels.is_empty() { null() } else { texels.as_ptr() };
                nmat_decode_texels_u8(h, at, texels.len(), call.mask, bytes.as_mut_ptr(), usize::from(call.pitch).min(bytes.len()))
            }
            _ => {
                let mut info = nmat_info::default();
                let mut ch = nmat_channel_info::default();
                let (mut w, mut hh) = (0u32, 0u32);
                nmat_material_info(h, &mut info);
                nmat_mip_size(h, call.c, &mut w, &mut hh);
                nmat_material_channel(h, call.c, &mut ch)
            }
        };
        let mut msg = [0u8; 64];
        nmat_last_error(msg.as_mut_ptr(), msg.len());
        nmat_status_message(call.mode as i32, msg.as_mut_ptr(), usize::from(call.len).min(msg.len()));
    }
    nmat_material_free(m);
});
