//! From trained float layers to the file's layers: int8 weights with per-row scales, i32 biases and
//! the fixed-point formats between layers.

use super::layers::{Dense, row_scale};
use nmat_core::{Activation, LayerSpec};

/// Hidden-layer output format: the most fraction bits whose i16 range (±2^(15−f)) holds the
/// observed activations with 25 % headroom.
pub fn frac_bits_for(max_abs: f32) -> u8 {
    let need = f64::from(max_abs.max(1e-3)) * 1.25;
    ((15.0 - need.log2()).floor() as i32).clamp(1, 14) as u8
}

/// The largest |bias| of a layer of `inputs` inputs (docs/FORMAT.md §5.3): with i16 inputs and
/// int8 weights no sum then leaves i32.
pub fn bias_limit(inputs: usize) -> f64 {
    f64::from(i32::MAX) - inputs as f64 * 127.0 * 32768.0
}

/// The smallest row scale between Q-formats `in_frac` and `out_frac`: the decoder needs its
/// requantization shift ≤ 62, so scale ≥ 2^(−32 + in − out), with margin.
pub fn min_row_scale(in_frac: u8, out_frac: u8) -> f32 {
    2f32.powi(-30 + i32::from(in_frac) - i32::from(out_frac))
}

/// Exports one trained layer to the file's two arithmetics. `out_rows` maps file rows to trained
/// rows (`None` = a constant channel: zero weights, zero scale).
pub fn export_layer(
    l: &Dense,
    in_frac: u8,
    out_frac: u8,
    out_rows: &[Option<usize>],
    activation: Activation,
) -> LayerSpec {
    let n = l.inputs;
    let min_scale = min_row_scale(in_frac, out_frac);
    let in_lsb = 1.0 / f64::from(1u32 << in_frac);
    let bias_limit = bias_limit(n);
    let (mut weights_i8, mut scales, mut bias) = (Vec::new(), Vec::new(), Vec::new());
    for row in out_rows {
        match row {
            Some(o) => {
                let w = &l.w[o * n..(o + 1) * n];
                let s = row_scale(w, l.b[*o], in_frac, min_scale);
                weights_i8.extend(w.iter().map(|v| (v / s).round().clamp(-127.0, 127.0) as i8));
                let b = (f64::from(l.b[*o]) / (f64::from(s) * in_lsb)).round();
                bias.push(b.clamp(-bias_limit, bias_limit) as i32);
                scales.push(s);
            }
            None => {
                weights_i8.extend(std::iter::repeat_n(0i8, n));
                scales.push(0.0);
                bias.push(0);
            }
        }
    }
    LayerSpec {
        inputs: n as u16,
        outputs: out_rows.len() as u16,
        out_frac_bits: out_frac,
        activation,
        weights_i8,
        scales,
        bias,
    }
}
