//! Adam, the optimizer of the MLP and (sparsely, through `latents`) of the latents.

/// Adam state for a flat parameter vector.
pub(super) struct Adam {
    pub(super) m: Vec<f32>,
    pub(super) v: Vec<f32>,
}

/// One step's Adam constants: learning rate and the bias corrections 1 − β^t.
#[derive(Clone, Copy)]
pub(super) struct AdamStep {
    pub(super) lr: f32,
    pub(super) c1: f32,
    pub(super) c2: f32,
}

pub(super) const B1: f32 = 0.9;

pub(super) const B2: f32 = 0.999;

impl AdamStep {
    pub(super) fn new(lr: f32, t: i32) -> AdamStep {
        AdamStep { lr, c1: 1.0 - B1.powi(t), c2: 1.0 - B2.powi(t) }
    }
}

impl Adam {
    pub(super) fn new(n: usize) -> Adam {
        Adam { m: vec![0.0; n], v: vec![0.0; n] }
    }
    /// Updates `params` with `grads` (one each, in order).
    pub(super) fn update(&mut self, params: &mut [f32], grads: &[f32], step: AdamStep) {
        adam_block(&mut self.m, &mut self.v, params, grads, step);
    }
}

/// [`adam`] over slices of equal length; a plain loop the compiler vectorizes (division and
/// square root are exact in every lane, so the results are those of [`adam`]).
pub(super) fn adam_block(m: &mut [f32], v: &mut [f32], p: &mut [f32], g: &[f32], step: AdamStep) {
    let n = p.len();
    assert!(m.len() == n && v.len() == n && g.len() == n, "adam_block: lengths");
    for i in 0..n {
        adam(&mut m[i], &mut v[i], &mut p[i], g[i], step);
    }
}

/// One Adam update of parameter `p` with gradient `g` and moments `m`, `v`.
#[inline(always)]
pub(super) fn adam(m: &mut f32, v: &mut f32, p: &mut f32, g: f32, step: AdamStep) {
    *m = B1 * *m + (1.0 - B1) * g;
    *v = B2 * *v + (1.0 - B2) * g * g;
    let mh = *m / step.c1;
    let vh = *v / step.c2;
    *p -= step.lr * mh / (vh.sqrt() + 1e-8);
}
