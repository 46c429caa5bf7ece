//! A second, deliberately naive implementation of the decode math of docs/FORMAT.md §6, written
//! from the spec text against the *owned* `MaterialSpec` (unpacked codes, plain vectors) rather
//! than the parsed file. It shares no code with `nmat-core`'s decoder: requantization uses exact
//! rationals in i128 instead of the multiplier/shift trick, rounding uses `div_euclid`, the float
//! path runs in f64. Agreement between the two is what the golden tests assert.

use nmat_core::{Activation, AddressMode, LayerSpec, MaterialSpec, TermMode};

fn mip_dims(spec: &MaterialSpec, mip: u32) -> (i64, i64) {
    ((i64::from(spec.width) >> mip).max(1), (i64::from(spec.height) >> mip).max(1))
}

fn wrap_or_clamp(i: i64, n: i64, mode: AddressMode) -> i64 {
    match mode {
        AddressMode::Wrap => ((i % n) + n) % n,
        AddressMode::Clamp => i.max(0).min(n - 1),
        other => panic!("reference does not know {other:?}"),
    }
}

/// §6.2: position in 1/256 of a cell of the texel centre, shifted by half a cell.
fn grid_axis(x: i64, mip_size: i64, grid_size: i64) -> (i64, i64) {
    let pos = ((2 * x + 1) * grid_size * 256).div_euclid(2 * mip_size) - 128;
    (pos.div_euclid(256), pos.rem_euclid(256))
}

fn latent(spec: &MaterialSpec, g: usize, x: i64, y: i64, c: usize) -> i64 {
    let grid = &spec.grids[g];
    let idx = (y as usize * usize::from(grid.width) + x as usize) * usize::from(grid.channels) + c;
    let (offset, step) = grid.quantization[c];
    i64::from(offset) + i64::from(grid.codes[idx]) * i64::from(step)
}

/// Input features as exact rationals n / 2^(16 + f) (§6.3–§6.4).
fn features(spec: &MaterialSpec, x: i64, y: i64, mip: u32) -> Vec<i64> {
    let (mw, mh) = mip_dims(spec, mip);
    let mode = spec.address_mode;
    let level = &spec.levels[usize::from(spec.mip_to_level[mip as usize])];
    let mut out = Vec::new();
    let cells = |g: usize| {
        let grid = &spec.grids[g];
        let (gw, gh) = (i64::from(grid.width), i64::from(grid.height));
        let (i, fx) = grid_axis(x, mw, gw);
        let (j, fy) = grid_axis(y, mh, gh);
        let xs = [wrap_or_clamp(i, gw, mode), wrap_or_clamp(i + 1, gw, mode)];
        let ys = [wrap_or_clamp(j, gh, mode), wrap_or_clamp(j + 1, gh, mode)];
        (xs, ys, fx, fy)
    };
    for term in &level.terms {
        match term.mode {
            TermMode::Nearest4 => {
                let g = usize::from(term.grids[0]);
                let (xs, ys, _, _) = cells(g);
                for (xi, yi) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    for c in 0..usize::from(spec.grids[g].channels) {
                        out.push(latent(spec, g, xs[xi], ys[yi], c) * 65536);
                    }
                }
            }
            TermMode::Bilinear => {
                let channels = usize::from(spec.grids[usize::from(term.grids[0])].channels);
                for c in 0..channels {
                    let mut sum = 0i64;
                    for &g in &term.grids {
                        let g = usize::from(g);
                        let (xs, ys, fx, fy) = cells(g);
                        let w =
                            [(256 - fx) * (256 - fy), fx * (256 - fy), (256 - fx) * fy, fx * fy];
                        let v = [
                            latent(spec, g, xs[0], ys[0], c),
                            latent(spec, g, xs[1], ys[0], c),
                            latent(spec, g, xs[0], ys[1], c),
                            latent(spec, g, xs[1], ys[1], c),
                        ];
                        sum += (0..4).map(|k| w[k] * v[k]).sum::<i64>();
                    }
                    out.push(sum);
                }
            }
            other => panic!("reference does not know {other:?}"),
        }
    }
    let f = u32::from(spec.mlp.input_frac_bits);
    for k in 0..u32::from(spec.mlp.pe_frequencies) {
        let period = 1i64 << (k + 2);
        for coord in [x, y] {
            for phase in [0, 1] {
                // The wave as an exact rational |2a − 2P| / 2P, moved to the 2^-(16+f) grid.
                let a = (2 * coord + 1 + phase * period / 2).rem_euclid(2 * period);
                let num = (2 * a - 2 * period).abs();
                out.push(num * (1i64 << (16 + f)) / (2 * period));
            }
        }
    }
    if spec.mlp.lod_input != 0 {
        // mip · 2^(code − 5): code 1 is mip / 16.
        let code = u32::from(spec.mlp.lod_input);
        out.push((i64::from(mip) << (16 + f + code)) / 32);
    }
    out
}

/// Exact `round_half_up(acc · scale · 2^(fo − fi))`: scale as an exact binary fraction m / 2^e.
fn requantize(acc: i64, scale: f32, in_frac: u32, out_frac: u32) -> i64 {
    let mut m = f64::from(scale);
    let mut e: i32 = 0;
    while m.fract() != 0.0 {
        m *= 2.0;
        e += 1;
    }
    let num = i128::from(acc) * (m as i128);
    let den_log2 = e + in_frac as i32 - out_frac as i32;
    if den_log2 <= 0 {
        return (num << (-den_log2)) as i64;
    }
    let den = 1i128 << den_log2;
    ((num + den / 2).div_euclid(den)) as i64
}

fn hard_gelu_int(z: i64, f: u32) -> i64 {
    let t = 3 * (1i64 << f) / 2;
    if z >= t {
        z
    } else if z <= -t {
        0
    } else {
        (z * (z + t) + t).div_euclid(3 << f)
    }
}

fn layer_int(l: &LayerSpec, x: &[i64], in_frac: u32) -> Vec<i64> {
    let n = usize::from(l.inputs);
    (0..usize::from(l.outputs))
        .map(|o| {
            let acc: i64 = i64::from(l.bias[o])
                + (0..n).map(|i| i64::from(l.weights_i8[o * n + i]) * x[i]).sum::<i64>();
            assert!(acc.abs() < 1 << 31, "accumulator out of i32 range: the bias bound failed");
            let y = requantize(acc, l.scales[o], in_frac, u32::from(l.out_frac_bits))
                .clamp(-32768, 32767);
            match l.activation {
                Activation::None => y,
                Activation::HardGelu => hard_gelu_int(y, u32::from(l.out_frac_bits)),
                other => panic!("reference does not know {other:?}"),
            }
        })
        .collect()
}

fn address(spec: &MaterialSpec, x: i64, y: i64, mip: u32) -> (i64, i64, u32) {
    let mip = mip.min(u32::from(spec.mip_count) - 1);
    let (w, h) = mip_dims(spec, mip);
    (wrap_or_clamp(x, w, spec.address_mode), wrap_or_clamp(y, h, spec.address_mode), mip)
}

/// The integer network's input vector of texel (x, y) of `mip`, addressed: the features rounded
/// to the input format's Q.f and saturated to i16 (§6.3).
pub fn input_vector(spec: &MaterialSpec, x: i64, y: i64, mip: u32) -> Vec<i64> {
    let (x, y, mip) = address(spec, x, y, mip);
    features(spec, x, y, mip)
        .into_iter()
        .map(|r| ((r + 32768).div_euclid(65536)).clamp(-32768, 32767))
        .collect()
}

/// Integer decode of every channel: the last layer's Q.f outputs.
pub fn decode_int_raw(spec: &MaterialSpec, x: i64, y: i64, mip: u32) -> Vec<i64> {
    let mut act = input_vector(spec, x, y, mip);
    let mut frac = u32::from(spec.mlp.input_frac_bits);
    for l in &spec.mlp.layers {
        act = layer_int(l, &act, frac);
        frac = u32::from(l.out_frac_bits);
    }
    act
}

fn to_code(y: i64, f: u32, max: i64) -> i64 {
    (y * max + (1 << (f - 1))).div_euclid(1 << f).clamp(0, max)
}

pub fn decode_u8(spec: &MaterialSpec, x: i64, y: i64, mip: u32) -> Vec<u8> {
    let f = u32::from(spec.mlp.layers.last().expect("a network has an output layer").out_frac_bits);
    decode_int_raw(spec, x, y, mip).into_iter().map(|v| to_code(v, f, 255) as u8).collect()
}

pub fn decode_u16(spec: &MaterialSpec, x: i64, y: i64, mip: u32) -> Vec<u16> {
    let f = u32::from(spec.mlp.layers.last().expect("a network has an output layer").out_frac_bits);
    decode_int_raw(spec, x, y, mip).into_iter().map(|v| to_code(v, f, 65535) as u16).collect()
}

/// The float network in f64, outputs clamped to [0, 1] (§6.5, §6.8).
pub fn decode_unit_f64(spec: &MaterialSpec, x: i64, y: i64, mip: u32) -> Vec<f64> {
    let (x, y, mip) = address(spec, x, y, mip);
    let scale = 2f64.powi(-(16 + i32::from(spec.mlp.input_frac_bits)));
    let lim = 32768.0 * 65536.0;
    let mut act: Vec<f64> = features(spec, x, y, mip)
        .into_iter()
        .map(|r| (r as f64).clamp(-lim, lim - 65536.0) * scale)
        .collect();
    let mut frac = i32::from(spec.mlp.input_frac_bits);
    for l in &spec.mlp.layers {
        let n = usize::from(l.inputs);
        // One network (§5.3): a real weight is code · scale, a real bias bias · scale · 2^−f_in.
        let lsb = 2f64.powi(-frac);
        act = (0..usize::from(l.outputs))
            .map(|o| {
                let s = f64::from(l.scales[o]);
                let z = f64::from(l.bias[o]) * s * lsb
                    + (0..n).map(|i| f64::from(l.weights_i8[o * n + i]) * s * act[i]).sum::<f64>();
                match l.activation {
                    Activation::HardGelu if z <= -1.5 => 0.0,
                    Activation::HardGelu if z < 1.5 => z * (z + 1.5) / 3.0,
                    _ => z,
                }
            })
            .collect();
        frac = i32::from(l.out_frac_bits);
    }
    act.into_iter().map(|v| v.clamp(0.0, 1.0)).collect()
}
