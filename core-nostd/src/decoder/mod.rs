//! A prepared decoder for throughput (docs/PERFORMANCE.md): the MLP's weights are re-laid once
//! — int8 widened to i16 and interleaved by input pairs so one SIMD multiply-add serves several
//! output rows, dequantized to f32 for the float path and transposed — and kept hot across
//! texels; spans go through the network 4 texels at a time.
//!
//! Every result is bit-identical to the per-texel definition on [`Material`] (FORMAT.md §6): the
//! integer sums are exact and the float sums keep the input order of `Layer::row_float`. The
//! integer layers run on one of several [`Kernel`]s: [`Kernel::Scalar`], portable Rust over the
//! prepared layout (the twin every SIMD kernel is tested against), [`Kernel::Avx2`] and
//! [`Kernel::Avx512Vnni`] on x86-64, [`Kernel::Neon`] and [`Kernel::NeonDot`] on AArch64 — chosen
//! at run time with the `std` feature, at compile time without it.
//!
//! Which file holds what:
//! - `mod.rs` (here): the [`Decoder`] API, the jobs it hands to a kernel (a span, a texel), the
//!   network over a texel or a group of texels, the first layer's periodic sums;
//! - `packed.rs`: one layer in the prepared layout (`PackedLayer`, private fields behind its
//!   constructors) and the scalar twin of the integer layer;
//! - `span.rs`: the inputs of consecutive texels of a row (the gather of a span);
//! - `texel.rs`: the inputs of single and scattered texels, with each grid's dequantization and
//!   each level's reads prepared once per decoder (the gather of random access);
//! - `transcode.rs`: regions decoded straight into BC blocks (`Decoder::transcode_blocks`);
//! - `kernel/mod.rs`: [`Kernel`], the `Layers` trait every kernel implements, and `run`, the one
//!   place a kernel is chosen; `kernel/{scalar,avx2,avx512,neon,neon_dot}.rs`: one instruction set
//!   each, with the lane tables (and, for `neon_dot`, the weight layout) it uses.

extern crate alloc;

use alloc::boxed::Box;
use alloc::vec::Vec;
use core::ops::Range;

use crate::decode::{ChannelMask, code, unit, write_selected};
use crate::error::{Argument, Error};
use crate::jpeg::Jpeg;
use crate::limits::MAX_WIDTH;
use crate::material::{Body, Material, Neural};
use crate::sample::filter::{Precision, SampleRequest};

mod kernel;
mod lanes;
mod packed;
mod span;
mod texel;
mod transcode;

pub use kernel::Kernel;
use kernel::{Available, GROUP, Job, Layers};
use packed::PackedLayer;
use span::{MAX_X_PERIOD, Slots, SpanGather};
use texel::TexelPlan;
pub use transcode::{BcTarget, BlockRegion};

/// The first layer's accumulators for the inputs of a span that repeat along x (the positional
/// encoding, whose period is at most `MAX_X_PERIOD` texels, and the span-constant features of y
/// and the LOD): bias plus their weighted sum, one row per texel of the period. Per texel only
/// the first `pairs` input pairs (the latent features) are left to sum; integer sums do not
/// depend on their order, so the result is the layer's to the bit.
struct PeriodicSums<'t> {
    pairs: usize,
    /// The period minus one (a power of two).
    mask: u32,
    table: &'t [[i32; MAX_WIDTH]; MAX_X_PERIOD],
}

impl PeriodicSums<'_> {
    /// The row of the texel at addressed x.
    fn at(&self, x: u32) -> &[i32] {
        self.table.get((x & self.mask) as usize).map_or(&[], |row| row.as_slice())
    }
}

/// The arguments of [`Decoder::span_codes`].
struct SpanJob<'j, 'a, T, N> {
    network: &'j Network,
    material: &'j Material<'a>,
    neural: &'j Neural<'a>,
    at: (i64, i64, u32),
    count: usize,
    rows: (u16, usize),
    out: &'j mut [T],
    full_scale: i32,
    narrow: N,
}

impl<T, N: Fn(i32) -> T> Job for SpanJob<'_, '_, T, N> {
    type Output = ();
    #[inline(always)]
    fn run<K: Layers>(self, kernel: K) {
        let SpanJob { network, material, neural, at, count, rows, out, full_scale, narrow } = self;
        let span = (at, count, rows);
        network.span_codes_here(kernel, (material, neural), span, out, full_scale, narrow);
    }
}

/// The arguments of [`Decoder::texel_codes`].
struct TexelJob<'j, 'a, T, N> {
    network: &'j Network,
    material: &'j Material<'a>,
    neural: &'j Neural<'a>,
    at: (i64, i64, u32),
    rows: u16,
    out: &'j mut [T],
    full_scale: i32,
    narrow: N,
}

impl<T, N: Fn(i32) -> T> Job for TexelJob<'_, '_, T, N> {
    type Output = usize;
    #[inline(always)]
    fn run<K: Layers>(self, kernel: K) -> usize {
        let TexelJob { network, material, neural, at, rows, out, full_scale, narrow } = self;
        network.texel_codes_here(kernel, (material, neural), at, rows, out, full_scale, narrow)
    }
}

/// A texel's address for [`Decoder::decode_texels_u8`]: column, row and mip, addressed like the
/// arguments of [`Decoder::decode_texel_u8`] (wrapped or clamped into the mip by the material's
/// address mode, the mip clamped to the chain). `#[repr(C)]`, with the fields of the C API's
/// `nmat_texel_at`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct TexelAt {
    /// Column.
    pub x: i64,
    /// Row.
    pub y: i64,
    /// Mip level (0 = full size).
    pub mip: u32,
}

/// The arguments of [`Decoder::texels_codes`].
struct TexelsJob<'j, 'a, T, N> {
    network: &'j Network,
    material: &'j Material<'a>,
    neural: &'j Neural<'a>,
    texels: &'j [TexelAt],
    rows: (u16, usize),
    out: &'j mut [T],
    full_scale: i32,
    narrow: N,
}

impl<T, N: Fn(i32) -> T> Job for TexelsJob<'_, '_, T, N> {
    type Output = ();
    #[inline(always)]
    fn run<K: Layers>(self, kernel: K) {
        let TexelsJob { network, material, neural, texels, rows, out, full_scale, narrow } = self;
        network.texels_codes_here(
            kernel,
            (material, neural),
            texels,
            rows,
            out,
            full_scale,
            narrow,
        );
    }
}

/// The MLP of one material, prepared for fast decoding (see the module documentation). It owns
/// its data and borrows nothing, so it can live next to the material in any handle; every call
/// takes the [`Material`] it was made from and refuses another one.
#[derive(Clone, Debug)]
pub struct Decoder {
    kernel: Available,
    prepared: Prepared,
    /// Address and length of the first layer's weights (or of the JPEG section) in the file:
    /// which material this is.
    identity: (usize, usize),
}

/// What a decoder prepared, by codec.
#[derive(Clone, Debug)]
enum Prepared {
    /// The network's layers, packed for the kernels, and the gather of single texels.
    Neural(Box<Network>),
    /// Nothing to prepare: the JPEG section is decoded as stored.
    Jpeg,
}

/// A neural material's network packed for the kernels.
#[derive(Clone, Debug)]
struct Network {
    layers: Vec<PackedLayer>,
    /// The gather of single and scattered texels, prepared.
    texels: TexelPlan,
}

/// The first layer's sums over a span's shared features — the `Nearest4` term's, the same for
/// every texel between two cell centres (FORMAT.md §6.2) — summed once per cell by the kernel
/// and added to each texel's start row (the bias, or its periodic sums), so that per texel only
/// the pairs after them are summed. Integer sums do not depend on their order: the layer's
/// result to the bit.
struct SharedSums<'l> {
    layer: &'l PackedLayer,
    /// The shared features are input pairs `0..skip`; a texel's own are `skip..end`.
    skip: usize,
    end: usize,
    /// The span gather's slot whose cells the shared features are.
    slot: usize,
    sums: [i32; MAX_WIDTH],
}

impl<'l> SharedSums<'l> {
    /// For a span of `gather` through kernel `K`, if the kernel saves the skipped pairs' work and
    /// the span has shared features ([`SpanGather::shared_pairs`]) and features of its own.
    fn new<K: Layers>(
        network: &'l Network,
        gather: &SpanGather<'_, '_, i16>,
        periodic: Option<&PeriodicSums<'_>>,
    ) -> Option<SharedSums<'l>> {
        let layer = network.layers.first().filter(|_| K::SKIPS_PAIRS)?;
        let (skip, slot) = gather.shared_pairs()?;
        let end = periodic.map_or(layer.in_pairs(), |p| p.pairs);
        let sums = [0; MAX_WIDTH];
        (skip > 0 && skip < end).then_some(SharedSums { layer, skip, end, slot, sums })
    }

    /// The pairs each texel sums itself.
    fn pairs(&self) -> Range<usize> {
        self.skip..self.end
    }

    /// The start row of the texel whose inputs `gather` just wrote into `x` (at addressed x
    /// `at`): its periodic sums (or the bias) plus the shared sums, summed again where the
    /// texel entered another cell.
    #[inline(always)]
    fn start<K: Layers>(
        &mut self,
        kernel: K,
        gather: &SpanGather<'_, '_, i16>,
        x: &[i16; MAX_WIDTH],
        periodic: Option<&PeriodicSums<'_>>,
        at: u32,
        start: &mut [i32; MAX_WIDTH],
    ) {
        if gather.changed(self.slot) {
            kernel.sums(self.layer, x, 0..self.skip, &mut self.sums);
        }
        let base = periodic.map_or(self.layer.bias(), |p| p.at(at));
        // 16 rows at a time (out_pad is a multiple of 16): fixed-length, vector code.
        let (to, _) = start.as_chunks_mut::<16>();
        let (from, _) = base.as_chunks::<16>();
        let (shared, _) = self.sums.as_chunks::<16>();
        let chunks = to.iter_mut().zip(from).zip(shared).take(self.layer.out_pad() / 16);
        for ((to, from), shared) in chunks {
            let mut sum = *from;
            for (s, &n) in sum.iter_mut().zip(shared) {
                *s = s.wrapping_add(n);
            }
            *to = sum;
        }
    }
}

/// A material checked against its decoder, by codec: what each entry point matches on.
#[derive(Clone, Copy)]
enum Bound<'d, 'm, 'a> {
    Neural(&'d Network, &'m Neural<'a>),
    Jpeg(&'m Jpeg<'a>),
}

fn identity(material: &Material<'_>) -> (usize, usize) {
    match material.body() {
        Body::Jpeg(jpeg) => (jpeg.section().as_ptr() as usize, jpeg.section().len()),
        Body::Neural(n) => n
            .mlp()
            .layers()
            .first()
            .map_or((0, 0), |l| (l.weights_i8.as_ptr() as usize, l.weights_i8.len())),
    }
}

impl Decoder {
    /// Prepares `material` for the fastest kernel of this CPU.
    pub fn new(material: &Material<'_>) -> Decoder {
        let prepared = match material.body() {
            Body::Neural(n) => Prepared::Neural(Box::new(Network {
                layers: n.mlp().layers().iter().map(PackedLayer::new).collect(),
                texels: TexelPlan::new(n),
            })),
            Body::Jpeg(_) => Prepared::Jpeg,
        };
        Decoder { kernel: Available::best(), prepared, identity: identity(material) }
    }

    /// Prepares `material` for a given kernel; `BadArgument(Kernel)` if this CPU lacks it.
    pub fn with_kernel(material: &Material<'_>, kernel: Kernel) -> Result<Decoder, Error> {
        let Some(kernel) = Available::new(kernel) else {
            return Err(Error::BadArgument {
                argument: Argument::Kernel,
                value: kernel as u64,
                limit: 0,
            });
        };
        Ok(Decoder { kernel, ..Decoder::new(material) })
    }

    /// The kernel computing the integer layers.
    pub fn kernel(&self) -> Kernel {
        self.kernel.kernel()
    }

    /// `material` with what this decoder prepared of it, or `BadArgument(Material)` if this
    /// decoder was made from another material.
    fn bind<'d, 'm, 'a>(&'d self, material: &'m Material<'a>) -> Result<Bound<'d, 'm, 'a>, Error> {
        let id = identity(material);
        if id == self.identity {
            match (&self.prepared, material.body()) {
                (Prepared::Neural(network), Body::Neural(n)) => {
                    return Ok(Bound::Neural(network, n));
                }
                (Prepared::Jpeg, Body::Jpeg(j)) => return Ok(Bound::Jpeg(j)),
                _ => {}
            }
        }
        Err(Error::BadArgument {
            argument: Argument::Material,
            value: id.0 as u64,
            limit: self.identity.0 as u64,
        })
    }
}

impl Network {
    /// Runs the integer layers on `x` (inputs on entry, outputs on exit).
    #[inline(always)]
    fn forward_int<K: Layers>(&self, kernel: K, x: &mut [i16; MAX_WIDTH], rows: u16) {
        let mut spare = [0i16; MAX_WIDTH];
        let (mut from, mut to) = (&mut *x, &mut spare);
        let count = self.layers.len();
        for (li, layer) in self.layers.iter().enumerate() {
            let blocks = layer.blocks(li + 1 == count, rows);
            kernel.forward(layer, from, to, blocks);
            // Rows past this layer's width may hold stale values: the next layer's padding
            // column has weight 0, and the last layer's unselected rows are never read.
            core::mem::swap(&mut from, &mut to);
        }
        if count % 2 == 1 {
            x.copy_from_slice(&spare);
        }
    }

    /// [`Decoder::forward_int`] for the first `count` texels of a group, batched (each weight
    /// loaded once for the group) by the SIMD kernels. With `first`, the first layer starts each
    /// texel from its row of sums (bias and the inputs summed ahead: the periodic ones, and those
    /// of cells the texels share) and sums only the pairs in the range; the SIMD kernels then
    /// compute the whole group (texels from `count` on are ignored).
    #[inline(always)]
    fn forward_int_group<K: Layers>(
        &self,
        kernel: K,
        xs: &mut [[i16; MAX_WIDTH]; GROUP],
        count: usize,
        rows: u16,
        first: Option<([&[i32]; GROUP], Range<usize>)>,
    ) {
        if count < GROUP && first.is_none() {
            for x in xs.iter_mut().take(count) {
                self.forward_int(kernel, x, rows);
            }
            return;
        }
        let mut first = first;
        let mut spare = [[0i16; MAX_WIDTH]; GROUP];
        let (mut from, mut to) = (&mut *xs, &mut spare);
        let layers = self.layers.len();
        for (li, layer) in self.layers.iter().enumerate() {
            let blocks = layer.blocks(li + 1 == layers, rows);
            let (init, pairs) = match first.take() {
                Some(start) => start,
                None => ([layer.bias(); GROUP], 0..layer.in_pairs()),
            };
            kernel.forward_group(layer, from, init, pairs, to, blocks, count);
            core::mem::swap(&mut from, &mut to);
        }
        if layers % 2 == 1 {
            *xs = spare;
        }
    }

    /// The first layer's sums over the inputs of `gather` that repeat along the row (positional
    /// encoding, LOD), one row per texel of the period, kept in `room` — when the inputs have
    /// such a tail and the span is long enough to repay the table.
    fn periodic_sums<'t>(
        &self,
        gather: &SpanGather<'_, '_, i16>,
        count: usize,
        room: &'t mut Option<[[i32; MAX_WIDTH]; MAX_X_PERIOD]>,
    ) -> Option<PeriodicSums<'t>> {
        let (latents, period) = gather.periodic_tail()?;
        let layer = self.layers.first()?;
        // Per texel: the pairs holding a latent feature (one may hold x's first feature too).
        let pairs = latents.div_ceil(2);
        // Building the table costs `period` texels' worth of the pairs it saves.
        if pairs >= layer.in_pairs() || count < 2 * period as usize {
            return None;
        }
        let table = room.insert([[0; MAX_WIDTH]; MAX_X_PERIOD]);
        let mut x = [0i16; MAX_WIDTH];
        for (phase, sums) in (0..period).zip(table.iter_mut()) {
            gather.fixed_inputs(phase, &mut x);
            layer.partial_sums(&x, pairs, sums);
        }
        Some(PeriodicSums { pairs, mask: period - 1, table })
    }

    #[inline(always)]
    fn span_codes_here<'a, T, K: Layers>(
        &self,
        kernel: K,
        (material, neural): (&Material<'a>, &Neural<'a>),
        ((x0, y, mip), count, (rows, n)): ((i64, i64, u32), usize, (u16, usize)),
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) {
        let mut slots = Slots::new();
        let mut gather = SpanGather::new(material, neural, y, mip, &mut slots);
        let f = neural.last_frac_bits();
        // Rows 0..n: the outputs are the first n values.
        let first_rows = rows & rows.wrapping_add(1) == 0;
        // Room for the table, filled (and zeroed first) only if the span uses it.
        let mut table = None;
        let periodic = self.periodic_sums(&gather, count, &mut table);
        let mut shared = SharedSums::new::<K>(self, &gather, periodic.as_ref());
        let mut xs = [[0i16; MAX_WIDTH]; GROUP];
        let mut at = [0u32; GROUP];
        let mut starts = [[0i32; MAX_WIDTH]; GROUP];
        for (g, texels) in out.chunks_mut(GROUP * n).take(count.div_ceil(GROUP)).enumerate() {
            let k = (count - g * GROUP).min(GROUP);
            let group = xs.iter_mut().zip(&mut at).zip(&mut starts).enumerate().take(k);
            for (i, ((x, at), start)) in group {
                *at = gather.inputs(x0.wrapping_add((g * GROUP + i) as i64), x);
                if let Some(shared) = shared.as_mut() {
                    shared.start(kernel, &gather, x, periodic.as_ref(), *at, start);
                }
            }
            let first = match (&shared, &periodic) {
                (Some(shared), _) => Some((starts.each_ref().map(|r| &r[..]), shared.pairs())),
                (None, Some(p)) => Some((at.map(|x| p.at(x)), 0..p.pairs)),
                (None, None) => None,
            };
            self.forward_int_group(kernel, &mut xs, k, rows, first);
            for (x, texel) in xs.iter().zip(texels.chunks_exact_mut(n)) {
                if first_rows {
                    // All 16 lanes at once (fixed length: vector code), then the n wanted.
                    let mut codes = [0i32; 16];
                    for (c, &v) in codes.iter_mut().zip(x) {
                        *c = code(v, f, full_scale);
                    }
                    for (out, &c) in texel.iter_mut().zip(&codes) {
                        *out = narrow(c);
                    }
                } else {
                    write_selected(rows, x, texel, |&v| narrow(code(v, f, full_scale)));
                }
            }
        }
    }

    /// Scattered texels, a group at a time: the inputs of all [`GROUP`] texels are gathered
    /// before any goes through the network, so their latents' cache misses are waited for
    /// together rather than one texel after the other, and each weight is loaded once per group.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn texels_codes_here<'a, T, K: Layers>(
        &self,
        kernel: K,
        (material, neural): (&Material<'a>, &Neural<'a>),
        texels: &[TexelAt],
        (rows, n): (u16, usize),
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) {
        let f = neural.last_frac_bits();
        let mut xs = [[0i16; MAX_WIDTH]; GROUP];
        for (group, codes) in texels.chunks(GROUP).zip(out.chunks_mut(GROUP * n)) {
            self.texels.inputs_group(material, neural, group, &mut xs);
            self.forward_int_group(kernel, &mut xs, group.len(), rows, None);
            for (x, texel) in xs.iter().zip(codes.chunks_exact_mut(n)) {
                write_selected(rows, x, texel, |&v| narrow(code(v, f, full_scale)));
            }
        }
    }

    fn forward_float(&self, x: &mut [f32; MAX_WIDTH]) {
        let mut y = [0f32; MAX_WIDTH];
        for layer in &self.layers {
            layer.forward_float(x, &mut y);
            core::mem::swap(x, &mut y);
        }
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn texel_codes_here<'a, T, K: Layers>(
        &self,
        kernel: K,
        (material, neural): (&Material<'a>, &Neural<'a>),
        (x, y, mip): (i64, i64, u32),
        rows: u16,
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) -> usize {
        let mut io = [0; MAX_WIDTH];
        self.texels.inputs(material, neural, (x, y, mip), &mut io);
        self.forward_int(kernel, &mut io, rows);
        let f = neural.last_frac_bits();
        write_selected(rows, &io, out, |&v| narrow(code(v, f, full_scale)))
    }

    /// The float decode of one texel: its inputs through the f32 layers.
    fn texel_float<'a>(
        &self,
        (material, neural): (&Material<'a>, &Neural<'a>),
        (x, y, mip): (i64, i64, u32),
    ) -> [f32; MAX_WIDTH] {
        let mut io = material.inputs(neural, x, y, mip);
        self.forward_float(&mut io);
        io
    }
}

impl Decoder {
    /// The integer codes of `count` texels of a span of `material` (`bound`: bound to this
    /// decoder once by the caller) into `out` (`n` values each), all of it compiled for the
    /// kernel's instruction set.
    #[allow(clippy::too_many_arguments)]
    fn span_codes<T>(
        &self,
        (material, bound): (&Material<'_>, Bound<'_, '_, '_>),
        at: (i64, i64, u32),
        count: usize,
        rows: (u16, usize),
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) {
        match bound {
            Bound::Jpeg(jpeg) => {
                let (x0, y, mip) = at;
                let (rows, n) = rows;
                let texel = |i: usize| {
                    let (x, y, _) = material.address_texel(x0.wrapping_add(i as i64), y, mip);
                    (x, y)
                };
                let mip = mip.min(material.mip_count() - 1);
                jpeg.span_codes(mip, count, rows, texel, |i, slot, _, c| {
                    if let Some(o) = out.get_mut(i * n + slot) {
                        *o = narrow(i32::from(c) * full_scale / 255);
                    }
                });
            }
            Bound::Neural(network, neural) => {
                let job =
                    SpanJob { network, material, neural, at, count, rows, out, full_scale, narrow };
                kernel::run(self.kernel, job);
            }
        }
    }

    /// Integer decode to 8-bit codes, bit-identical to [`Material::decode_texel_u8`].
    pub fn decode_texel_u8(
        &self,
        material: &Material<'_>,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [u8],
    ) -> Result<usize, Error> {
        let rows = material.check_out(channels, out.len())?;
        self.texel_codes(material, (x, y, mip), rows, out, 255, |c| c as u8)
    }

    /// Integer decode of scattered texels to 8-bit codes: texel `i` of `texels` into
    /// `out[i·n..(i + 1)·n]`, `n` the channels selected; each texel's codes bit-identical to
    /// [`Decoder::decode_texel_u8`]'s. For random access to many texels (a ray tracer's hit
    /// points, a scattered lookup) this is the faster call: a few texels at a time have their
    /// latents fetched together and go through the network together (docs/PERFORMANCE.md).
    /// Returns how many values were written (`texels.len() · n`); an `out` shorter than that is
    /// `BadArgument(Output)`.
    pub fn decode_texels_u8(
        &self,
        material: &Material<'_>,
        texels: &[TexelAt],
        channels: ChannelMask,
        out: &mut [u8],
    ) -> Result<usize, Error> {
        self.texels_codes(material, texels, channels, out, 255, |c| c as u8)
    }

    /// [`Decoder::decode_texels_u8`] to 16-bit codes, each texel's bit-identical to
    /// [`Decoder::decode_texel_u16`]'s.
    pub fn decode_texels_u16(
        &self,
        material: &Material<'_>,
        texels: &[TexelAt],
        channels: ChannelMask,
        out: &mut [u16],
    ) -> Result<usize, Error> {
        self.texels_codes(material, texels, channels, out, 65535, |c| c as u16)
    }

    /// Integer decode to 16-bit codes, bit-identical to [`Material::decode_texel_u16`].
    pub fn decode_texel_u16(
        &self,
        material: &Material<'_>,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [u16],
    ) -> Result<usize, Error> {
        let rows = material.check_out(channels, out.len())?;
        self.texel_codes(material, (x, y, mip), rows, out, 65535, |c| c as u16)
    }

    /// Float decode (values in channel ranges) with f32 weights, bit-identical to
    /// [`Material::decode_texel`] (which dequantizes each weight where it uses it).
    pub fn decode_texel(
        &self,
        material: &Material<'_>,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        let rows = material.check_out(channels, out.len())?;
        let io = match self.bind(material)? {
            Bound::Neural(network, neural) => network.texel_float((material, neural), (x, y, mip)),
            Bound::Jpeg(_) => material.run_float(x, y, mip, rows),
        };
        Ok(material.write_ranged(rows, &io, out))
    }

    /// Filtered sample, equal to [`Material::sample`] but decoding its texels with this
    /// decoder (a bilinear sample is 4 texel decodes, a trilinear one 8).
    pub fn sample(
        &self,
        material: &Material<'_>,
        req: &SampleRequest,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        let bound = self.bind(material)?;
        material.sample_with(req, out, &|x, y, mip, channels, precision, out| {
            let rows = material.check_out(channels, out.len())?;
            match (precision, &bound) {
                (Precision::Float, Bound::Neural(network, neural)) => {
                    let io = network.texel_float((material, neural), (x, y, mip));
                    Ok(write_selected(rows, &io, out, |v| unit(*v)))
                }
                (Precision::Float, Bound::Jpeg(_)) => {
                    let io = material.run_float(x, y, mip, rows);
                    Ok(write_selected(rows, &io, out, |v| unit(*v)))
                }
                (Precision::Integer, _) => {
                    self.texel_codes(material, (x, y, mip), rows, out, 255, |c| c as f32 / 255.0)
                }
            }
        })
    }

    /// Integer decode of `count` consecutive texels of row `y` from column `x0` (addressed like
    /// single texels), packed: `count · channels` codes. Returns how many values were written.
    #[allow(clippy::too_many_arguments)] // a texel address, a span, a mask and the output
    pub fn decode_span_u8(
        &self,
        material: &Material<'_>,
        x0: i64,
        y: i64,
        mip: u32,
        count: usize,
        channels: ChannelMask,
        out: &mut [u8],
    ) -> Result<usize, Error> {
        let (bound, rows, n) = self.check_span(material, count, channels, out.len())?;
        let at = (x0, y, mip);
        self.span_codes((material, bound), at, count, (rows, n), out, 255, |c| c as u8);
        Ok(count * n)
    }

    /// Integer decode of the rectangle (x0, y0, width, height) of `mip`, which must lie inside
    /// the mip, into rows of `width · channels` codes starting `row_pitch` bytes apart (0:
    /// packed) in `out`. The same codes as [`Decoder::decode_span_u8`] row by row; for a JPEG
    /// material each MCU the rectangle touches is decoded once, where a span decodes it once per
    /// row (8–16 times fewer MCU decodes). Returns the codes per row.
    #[allow(clippy::too_many_arguments)] // a rectangle, a mask and the output with its pitch
    pub fn decode_region_u8(
        &self,
        material: &Material<'_>,
        mip: u32,
        (x0, y0, width, height): (u32, u32, u32, u32),
        channels: ChannelMask,
        out: &mut [u8],
        row_pitch: usize,
    ) -> Result<usize, Error> {
        let bound = self.bind(material)?;
        if mip >= material.mip_count() {
            return Err(Error::BadArgument {
                argument: Argument::Mip,
                value: u64::from(mip),
                limit: u64::from(material.mip_count()),
            });
        }
        let (mw, mh) = material.mip_size(mip);
        let (x1, y1) = (u64::from(x0) + u64::from(width), u64::from(y0) + u64::from(height));
        if x1 > u64::from(mw) || y1 > u64::from(mh) {
            let (value, limit) = if x1 > u64::from(mw) { (x1, mw) } else { (y1, mh) };
            return Err(Error::BadArgument {
                argument: Argument::Region,
                value,
                limit: u64::from(limit),
            });
        }
        let rows = material.resolve_channels(channels)?;
        let n = rows.count_ones() as usize;
        let row_len = width as usize * n;
        let pitch = if row_pitch == 0 { row_len } else { row_pitch };
        if pitch < row_len {
            return Err(Error::BadArgument {
                argument: Argument::RowPitch,
                value: pitch as u64,
                limit: row_len as u64,
            });
        }
        let needed = match height {
            0 => Some(0),
            h => pitch.checked_mul(h as usize - 1).and_then(|v| v.checked_add(row_len)),
        };
        let Some(needed) = needed else {
            return Err(Error::BadArgument {
                argument: Argument::RowPitch,
                value: pitch as u64,
                limit: (usize::MAX / (height as usize).max(1)) as u64,
            });
        };
        if out.len() < needed {
            return Err(Error::BadArgument {
                argument: Argument::Output,
                value: out.len() as u64,
                limit: needed as u64,
            });
        }
        match bound {
            Bound::Jpeg(jpeg) => {
                jpeg.region_codes(mip, (x0, y0, width, height), rows, |x, y, slot, code| {
                    if let Some(o) = out.get_mut(y as usize * pitch + x as usize * n + slot) {
                        *o = code;
                    }
                });
            }
            Bound::Neural(..) => {
                for y in 0..height as usize {
                    if let Some(row) = out.get_mut(y * pitch..y * pitch + row_len) {
                        let at = (i64::from(x0), i64::from(y0) + y as i64, mip);
                        let (span, texels) = ((rows, n), width as usize);
                        self.span_codes((material, bound), at, texels, span, row, 255, |c| c as u8);
                    }
                }
            }
        }
        Ok(row_len)
    }

    /// Integer decode of a span to 16-bit codes, like [`Decoder::decode_span_u8`].
    #[allow(clippy::too_many_arguments)]
    pub fn decode_span_u16(
        &self,
        material: &Material<'_>,
        x0: i64,
        y: i64,
        mip: u32,
        count: usize,
        channels: ChannelMask,
        out: &mut [u16],
    ) -> Result<usize, Error> {
        let (bound, rows, n) = self.check_span(material, count, channels, out.len())?;
        let at = (x0, y, mip);
        self.span_codes((material, bound), at, count, (rows, n), out, 65535, |c| c as u16);
        Ok(count * n)
    }

    /// Float decode (values in channel ranges) of a span, like [`Decoder::decode_span_u8`].
    #[allow(clippy::too_many_arguments)]
    pub fn decode_span_f32(
        &self,
        material: &Material<'_>,
        x0: i64,
        y: i64,
        mip: u32,
        count: usize,
        channels: ChannelMask,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        let (bound, rows, n) = self.check_span(material, count, channels, out.len())?;
        let (network, neural) = match bound {
            Bound::Neural(network, neural) => (network, neural),
            Bound::Jpeg(jpeg) => {
                // Each code in unit scale (c / 255), mapped into its channel's range.
                let texel = |i: usize| {
                    let (x, y, _) = material.address_texel(x0.wrapping_add(i as i64), y, mip);
                    (x, y)
                };
                let mip = mip.min(material.mip_count() - 1);
                jpeg.span_codes(mip, count, rows, texel, |i, slot, channel, c| {
                    if let (Some(o), Some(ch)) =
                        (out.get_mut(i * n + slot), material.channels().get(channel))
                    {
                        *o = crate::decode::ranged(ch, f32::from(c) / 255.0);
                    }
                });
                return Ok(count * n);
            }
        };
        let mut slots = Slots::new();
        let mut gather = SpanGather::new(material, neural, y, mip, &mut slots);
        let mut io = [0f32; MAX_WIDTH];
        for (i, texel) in out.chunks_exact_mut(n).take(count).enumerate() {
            gather.inputs(x0.wrapping_add(i as i64), &mut io);
            network.forward_float(&mut io);
            material.write_ranged(rows, &io, texel);
        }
        Ok(count * n)
    }

    /// `material` bound to this decoder, and the rows and count of the channels of a span of
    /// `count` texels into `out_len` values, checked.
    fn check_span<'d, 'm, 'a>(
        &'d self,
        material: &'m Material<'a>,
        count: usize,
        channels: ChannelMask,
        out_len: usize,
    ) -> Result<(Bound<'d, 'm, 'a>, u16, usize), Error> {
        let bound = self.bind(material)?;
        let rows = material.resolve_channels(channels)?;
        let n = rows.count_ones() as usize;
        let needed = count.saturating_mul(n);
        if out_len < needed {
            return Err(Error::BadArgument {
                argument: Argument::Output,
                value: out_len as u64,
                limit: needed as u64,
            });
        }
        Ok((bound, rows, n))
    }

    /// The integer codes of scattered `texels` into `out`, checked; a JPEG material's through
    /// [`Decoder::texel_codes`], texel by texel (each decodes its MCUs).
    fn texels_codes<T>(
        &self,
        material: &Material<'_>,
        texels: &[TexelAt],
        channels: ChannelMask,
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) -> Result<usize, Error> {
        let (bound, rows, n) = self.check_span(material, texels.len(), channels, out.len())?;
        match bound {
            Bound::Jpeg(_) => {
                for (t, texel) in texels.iter().zip(out.chunks_exact_mut(n)) {
                    let at = (t.x, t.y, t.mip);
                    self.texel_codes(material, at, rows, texel, full_scale, &narrow)?;
                }
            }
            Bound::Neural(network, neural) => {
                let rows = (rows, n);
                let job =
                    TexelsJob { network, material, neural, texels, rows, out, full_scale, narrow };
                kernel::run(self.kernel, job);
            }
        }
        Ok(texels.len() * n)
    }

    /// The integer codes of one texel into `out`, all of it (the gather too) compiled for the
    /// kernel's instruction set. Returns how many values were written.
    fn texel_codes<T>(
        &self,
        material: &Material<'_>,
        at: (i64, i64, u32),
        rows: u16,
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) -> Result<usize, Error> {
        Ok(match self.bind(material)? {
            Bound::Jpeg(j) => {
                let codes = material.jpeg_codes(j, at.0, at.1, at.2, rows);
                write_selected(rows, &codes, out, |&c| narrow(i32::from(c) * full_scale / 255))
            }
            Bound::Neural(network, neural) => {
                let job = TexelJob { network, material, neural, at, rows, out, full_scale, narrow };
                kernel::run(self.kernel, job)
            }
        })
    }
}
