//! The MLP's layers as the trainer holds them (`Dense`), as the forward and backward passes use
//! them (`EvalLayer`, fake-quantized in the quantization-aware phase), and the activation.

use crate::gemm::Matrix;

#[derive(Clone, Debug)]
pub struct Dense {
    pub inputs: usize,
    pub outputs: usize,
    pub hidden: bool,
    /// Row-major `[outputs][inputs]`.
    pub w: Vec<f32>,
    pub b: Vec<f32>,
}

/// Weights as the forward pass uses them (possibly fake-quantized), in both layouts.
pub(super) struct EvalLayer {
    pub(super) inputs: usize,
    pub(super) outputs: usize,
    pub(super) hidden: bool,
    /// `[inputs][outputs]`: the forward product `x · wᵀ`.
    pub(super) wt: Matrix,
    /// `[outputs][inputs]`: the backward product `g · w`.
    pub(super) w: Matrix,
    /// Padded to the columns of `wt`.
    pub(super) b: Vec<f32>,
}

/// Per-row int8 scale: max |w| / 127, but never so small that the row's bias (in accumulator
/// units, `bias / (scale · 2^−in_frac)`) leaves the decoder's bias bound, nor below `min_scale`
/// (the decoder's shift range). A row whose weights died during training but whose bias carries
/// the output is the case the bias term exists for.
pub fn row_scale(row: &[f32], bias: f32, in_frac_bits: u8, min_scale: f32) -> f32 {
    let max = row.iter().fold(0f32, |m, w| m.max(w.abs()));
    let bias_limit = f64::from(i32::MAX) - row.len() as f64 * 127.0 * 32768.0;
    let for_bias = (f64::from(bias.abs()) * f64::from(1u32 << in_frac_bits) / bias_limit) as f32;
    (max / 127.0).max(for_bias * 1.01).max(min_scale)
}

pub(super) fn eval_layers(layers: &[Dense], fake_quant: bool) -> Vec<EvalLayer> {
    layers
        .iter()
        .map(|l| {
            let mut w = l.w.clone();
            if fake_quant {
                for (row, &b) in w.chunks_mut(l.inputs).zip(&l.b) {
                    // The hidden Q-formats are chosen after training: bound by the finest.
                    let s = row_scale(row, b, nmat_core::limits::MAX_FRAC_BITS, 1e-12);
                    row.iter_mut().for_each(|v| *v = (*v / s).round().clamp(-127.0, 127.0) * s);
                }
            }
            let mut wt = Matrix::zeros(l.inputs, l.outputs);
            let mut wo = Matrix::zeros(l.outputs, l.inputs);
            for (o, row) in w.chunks(l.inputs).enumerate() {
                wo.row_mut(o)[..l.inputs].copy_from_slice(row);
                for (i, &v) in row.iter().enumerate() {
                    wt.row_mut(i)[o] = v;
                }
            }
            let mut b = vec![0f32; wt.stride()];
            b[..l.outputs].copy_from_slice(&l.b);
            EvalLayer { inputs: l.inputs, outputs: l.outputs, hidden: l.hidden, wt, w: wo, b }
        })
        .collect()
}

// Both activations compute the middle piece unconditionally, so a loop over a chunk can select
// instead of branch.
pub(super) fn hard_gelu(x: f32) -> f32 {
    let mid = x * (x + 1.5) / 3.0;
    if x <= -1.5 {
        0.0
    } else if x >= 1.5 {
        x
    } else {
        mid
    }
}

pub(super) fn hard_gelu_grad(x: f32) -> f32 {
    let mid = (2.0 * x + 1.5) / 3.0;
    if x <= -1.5 {
        0.0
    } else if x >= 1.5 {
        1.0
    } else {
        mid
    }
}
