//! A procedural brick material (albedo, normal, roughness, height) made in code: the bundled
//! sample of `nmat demo` and the material of the encoder's tests. No external data, no license.

use crate::texset::{ChannelInfo, FileLayout, Role, SourceMap, TextureSet, build_mips};

fn hash(x: i64, y: i64, seed: u64) -> f32 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Smooth value noise with period `period` texels (tiles when it divides the size).
fn value_noise(x: f32, y: f32, cell: f32, period: i64, seed: u64) -> f32 {
    let (fx, fy) = (x / cell, y / cell);
    let (ix, iy) = (fx.floor() as i64, fy.floor() as i64);
    let (tx, ty) = (fx - ix as f32, fy - iy as f32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let at = |i: i64, j: i64| hash(i.rem_euclid(period), j.rem_euclid(period), seed);
    let a = at(ix, iy) + (at(ix + 1, iy) - at(ix, iy)) * s(tx);
    let b = at(ix, iy + 1) + (at(ix + 1, iy + 1) - at(ix, iy + 1)) * s(tx);
    a + (b - a) * s(ty)
}

/// A `size × size` tiling brick wall (size a multiple of 32).
pub fn bricks(size: u32) -> TextureSet {
    let n = (size * size) as usize;
    let (bw, bh) = (size as f32 / 4.0, size as f32 / 8.0);
    let mut height = vec![0f32; n];
    let mut tint = vec![0f32; n];
    for y in 0..size {
        for x in 0..size {
            let row = (y as f32 / bh).floor();
            let shift = if row as i64 % 2 == 1 { bw / 2.0 } else { 0.0 };
            let u = (x as f32 + shift) % size as f32;
            let (bx, by) = ((u / bw).floor(), row);
            let (lx, ly) = (u - bx * bw, y as f32 - by * bh);
            let edge = lx.min(bw - lx).min(ly).min(bh - ly);
            let mortar = (edge / 2.0).clamp(0.0, 1.0);
            let grain = value_noise(x as f32, y as f32, size as f32 / 32.0, 32, 3);
            let i = (y * size + x) as usize;
            height[i] = (0.25 + 0.55 * mortar + 0.2 * grain * mortar).clamp(0.0, 1.0);
            tint[i] = hash(bx as i64 % 4, by as i64, 9) * mortar;
        }
    }
    let mut planes: Vec<Vec<f32>> = (0..8).map(|_| Vec::with_capacity(n)).collect();
    let s = size as i64;
    for y in 0..s {
        for x in 0..s {
            let i = (y * s + x) as usize;
            let h = |dx: i64, dy: i64| {
                height[(((y + dy).rem_euclid(s)) * s + (x + dx).rem_euclid(s)) as usize]
            };
            let (gx, gy) = ((h(1, 0) - h(-1, 0)) * 4.0, (h(0, 1) - h(0, -1)) * 4.0);
            let len = (gx * gx + gy * gy + 1.0).sqrt();
            let fine = value_noise(x as f32, y as f32, 2.0, s / 2, 5);
            let t = tint[i];
            let mortar = 1.0 - ((height[i] - 0.25) / 0.55).clamp(0.0, 1.0);
            let albedo = [
                0.55 + 0.25 * t - 0.25 * mortar + 0.08 * fine,
                0.28 + 0.10 * t + 0.15 * mortar + 0.06 * fine,
                0.20 + 0.05 * t + 0.25 * mortar + 0.05 * fine,
            ];
            for (k, a) in albedo.iter().enumerate() {
                planes[k].push(a.clamp(0.0, 1.0));
            }
            planes[3].push(0.5 - 0.5 * gx / len);
            planes[4].push(0.5 - 0.5 * gy / len);
            planes[5].push(0.5 + 0.5 / len);
            planes[6].push((0.45 + 0.4 * mortar + 0.15 * fine).clamp(0.0, 1.0));
            planes[7].push(height[i]);
        }
    }
    let channel = |name: &str, role, component| ChannelInfo {
        name: name.into(),
        role,
        component,
        constant: None,
    };
    let channels = vec![
        channel("albedo.r", Role::Albedo, 0),
        channel("albedo.g", Role::Albedo, 1),
        channel("albedo.b", Role::Albedo, 2),
        channel("normal.x", Role::Normal, 0),
        channel("normal.y", Role::Normal, 1),
        channel("normal.z", Role::Normal, 2),
        channel("roughness", Role::Roughness, 0),
        channel("height", Role::Height, 0),
    ];
    let map = |role: Role, file: &str, layout, first, count| SourceMap {
        role,
        file_name: file.into(),
        layout,
        first_channel: first,
        channel_count: count,
        gray_rgb: false,
        alpha_value: None,
        sixteen_bit: false,
    };
    let maps = vec![
        map(Role::Albedo, "bricks_albedo.png", FileLayout::Rgb, 0, 3),
        map(Role::Normal, "bricks_normal.png", FileLayout::Rgb, 3, 3),
        map(Role::Roughness, "bricks_roughness.png", FileLayout::Gray, 6, 1),
        map(Role::Height, "bricks_height.png", FileLayout::Gray, 7, 1),
    ];
    // Quantize to 8 bits like a map read from disk, so "lossless" means what it does for files.
    let planes = planes
        .into_iter()
        .map(|p| p.into_iter().map(|v| (v * 255.0).round() / 255.0).collect())
        .collect();
    TextureSet { width: size, height: size, channels, maps, mips: build_mips(size, size, planes) }
}
