//! The numerical extremes of the integer decoder (those of `tests/tests/extremes.rs`, which
//! checks the CPU against the definition) and random valid materials, on the GPU: every kernel
//! the device runs, and the matrix kernel with its matrix operations emulated, against the CPU
//! byte for byte. The golden fixtures and trained materials of `bitexact.rs` have sums far from
//! the accumulator's bound, codes far from the clamps and common network shapes; here are the
//! materials where a kernel's shortcut would show: a fan-in of 128 with every weight ±127, every
//! input at ±2^15 and the bias at the format's limit (the dot4 split's bytes at −128, the matrix
//! kernel's f32 sums at their largest, requantization into saturation), latents all 0, all
//! maximal and alternating at 1 and 8 bits a code, outputs saturating both ways, all-zero
//! weights, a zero scale, fused grids that saturate, a 16384² chain (the positional encoding's
//! phase and the addressing at the largest size), random sizes, layouts, bit depths, Q-formats
//! and layer widths (odd widths the generated kernels pad), and the widest network the format
//! allows.
//! Each upload's tile entry must pass its probe too (`tile_kernel` the kernel itself).
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{ChannelMask, Container, Material, MaterialSpec};
use nmat_tests::decode_all_u8;
use nmat_tests::generate::{
    BIAS_LIMIT_128, FixtureConfig, Layout, accumulator_corners, generate, largest_material,
    random_config, set_codes, sixteen_grids_in_one_level, terms_in_any_order, wide_cells,
    wide_constant_material,
};
use nmat_wgpu::{Context, GpuError, GpuMaterial, Kernel, TexelRequest};

mod common;
use common::{
    MATRIX_TOO_LARGE, assert_same_bytes, cpu_codes, device, device_with_f16, each_kernel,
    random_requests,
};

/// The default device (with cooperative matrices where the adapter has them, and then f16),
/// or where it lacks f16 (lavapipe) one with f16, which the matrix kernel's emulation needs; a
/// `Context` for the kernels the device runs, one whose matrix kernel is emulated, and one
/// whose emulated matrix kernel reads its weights from a storage buffer instead of staging them
/// (for networks whose weights exceed the workgroup memory).
struct Gpu {
    device: wgpu::Device,
    queue: wgpu::Queue,
    ctx: Context,
    /// The two emulated matrix kernels; `None` on wgpu's GL backend, which has no f16.
    emulated: Option<(Context, Context)>,
}

impl Gpu {
    fn new() -> Gpu {
        let (mut device, mut queue) = device();
        let mut f16 = device.features().contains(wgpu::Features::SHADER_F16);
        if !f16 && let Some(with_f16) = device_with_f16() {
            (device, queue) = with_f16;
            f16 = true;
        }
        let ctx = Context::new(&device);
        let emulated = f16.then(|| {
            let emulated = Context::new(&device);
            emulated.emulate_matrix_for_testing(false, false);
            let emulated_storage = Context::new(&device);
            emulated_storage.emulate_matrix_for_testing(false, true);
            (emulated, emulated_storage)
        });
        Gpu { device, queue, ctx, emulated }
    }

    /// `m` through every kernel: each upload with the `Context` that decodes it. Each kernel's
    /// probe equals the CPU (else the upload fails), and so does its tile entry's. The emulated
    /// matrix kernel must take `m`; where it refuses because the staged weights exceed the
    /// workgroup memory, the variant with the weights in storage must.
    fn uploads(&self, name: &str, m: &Material<'_>) -> Vec<(&Context, GpuMaterial)> {
        let mut uploads: Vec<(&Context, GpuMaterial)> =
            each_kernel(&self.ctx, &self.device, &self.queue, m)
                .into_iter()
                .map(|gm| (&self.ctx, gm))
                .collect();
        if let Some((emulated, emulated_storage)) = &self.emulated {
            match emulated.upload_with(&self.device, &self.queue, m, Some(Kernel::Matrix)) {
                Ok(gm) => uploads.push((emulated, gm)),
                Err(GpuError::Kernel { kernel: Kernel::Matrix, reason })
                    if reason.contains(MATRIX_TOO_LARGE) =>
                {
                    eprintln!("{name}: the emulated matrix kernel refused it: {reason}");
                    let matrix = Some(Kernel::Matrix);
                    let gm = emulated_storage.upload_with(&self.device, &self.queue, m, matrix);
                    uploads.push((emulated_storage, gm.unwrap()));
                }
                Err(e) => panic!("{name}, emulated matrix kernel: {e}"),
            }
        }
        for (_, gm) in &uploads {
            assert_eq!(gm.tile_kernel(), gm.kernel(), "{name}: the tile entry's probe differs");
        }
        uploads
    }

    /// Every code of every mip of `spec`, and random requests with a channel subset, equal the
    /// CPU's through every kernel.
    fn agree(&self, name: &str, spec: &MaterialSpec) {
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let cpu = decode_all_u8(&m);
        let n = m.channel_count();
        // The odd channels: a subset without channel 0 (channel 0 alone for one channel).
        let odd = ChannelMask(if n == 1 { 1 } else { (0xaaaa & ((1u32 << n) - 1)) as u16 });
        let reqs = random_requests(name.len() as u64, 150, 300, m.mip_count() + 2);
        let cpu_reqs = cpu_codes(&m, &reqs, odd);
        for (ctx, gm) in self.uploads(name, &m) {
            let kernel = gm.kernel();
            let emulated = if std::ptr::eq(ctx, &self.ctx) { "" } else { " (emulated)" };
            let gpu = ctx.decode_chain(&self.device, &self.queue, &gm, ChannelMask::ALL).unwrap();
            assert_same_bytes(&gpu, &cpu, format!("{name}, {kernel:?}{emulated}"));
            let gpu = ctx.decode_requests(&self.device, &self.queue, &gm, &reqs, odd).unwrap();
            assert_eq!(gpu, cpu_reqs, "{name}, {kernel:?}{emulated}: requests, {odd:?}");
        }
    }
}

fn small(name: &'static str) -> MaterialSpec {
    generate(&FixtureConfig::ntc(name, 11, 16, 12, 3))
}

/// The accumulator at the format's bound: 128 inputs at ±2^15 (i16::MIN's high byte is −128),
/// every weight ±127, the bias at ±(2^31 − 1 − 128 · 127 · 2^15) — each sign combination
/// (FORMAT.md §5.3; `tests/tests/extremes.rs` checks the CPU against i64 sums) — then the sum
/// at its positive extreme against the bias at its negative one, and a sum of −128 · 127 with
/// no bias.
#[test]
fn the_accumulator_at_its_bound_decodes_as_on_the_cpu() {
    let gpu = Gpu::new();
    let more = [(i16::MIN, -127, -BIAS_LIMIT_128), (-1, 127, 0)];
    for (input, weight, bias) in accumulator_corners().into_iter().chain(more) {
        let name = format!("input {input}, weight {weight}, bias {bias}");
        gpu.agree(&name, &wide_constant_material(input, weight, bias));
    }
}

/// Latents at their extremes, outputs that saturate, weights that vanish: all 0, all maximal
/// and alternating codes at 1 and 8 bits; a last layer whose bias drives every output past both
/// ends of the code range; all-zero weights (the output is the bias); a zero scale (the channel
/// is constant 0); three fused NBC grids at +32767 each (the input saturates at i16).
#[test]
fn extreme_latents_and_outputs_decode_as_on_the_cpu() {
    let gpu = Gpu::new();
    type Pattern = fn(usize, u8) -> u8;
    let patterns: [(&str, Pattern); 3] = [
        ("max", |_, max| max),
        ("zero", |_, _| 0),
        ("alternating", |i, max| if i % 2 == 0 { max } else { 0 }),
    ];
    // One layout for both depths (a shape to compile, not two): the high-resolution grid at 1
    // bit a code, the low-resolution one at 8.
    let cfg = FixtureConfig {
        layout: Layout::Ntc { hi_channels: 3, lo_channels: 2, hi_bits: 1, lo_bits: 8 },
        ..FixtureConfig::ntc("lat", 13, 24, 20, 2)
    };
    for (pattern_name, pattern) in patterns {
        let mut spec = generate(&cfg);
        set_codes(&mut spec, pattern);
        gpu.agree(&format!("latents {pattern_name} at 1 and 8 bits"), &spec);
    }
    // At scale 1 the 32-bit requantization (requant.wgsl) multiplies these sums by m'/2^u = 4
    // (the scale times 2^(14 − 12), output and hidden Q-formats); at 1024 and 1000 (a power of
    // two, and a mantissa with fewer trailing zeros) by about 4000. The sum is clamped to the
    // row's saturation range first: near ±2^31 its f32 estimate exceeds i32 by far. Without
    // that clamp the negative sums at 1024 and 1000 come out wrong on lavapipe (the estimate at
    // i32's least, minus 1, wraps), scale 1 and the positive sums by chance do not.
    for (scale, sign) in [(1.0, 1i64), (1.0, -1), (1024.0, 1), (1024.0, -1), (1000.0, -1)] {
        let mut spec = small("clamp");
        let last = spec.mlp.layers.last_mut().unwrap();
        let limit = i64::from(i32::MAX) - i64::from(last.inputs) * 127 * 32768;
        last.bias = vec![(sign * limit) as i32; 3];
        last.scales = vec![scale; 3];
        gpu.agree(&format!("outputs saturating, scale {scale}, bias sign {sign}"), &spec);
    }
    let mut spec = small("zw");
    spec.mlp.layers.iter_mut().for_each(|l| l.weights_i8.iter_mut().for_each(|w| *w = 0));
    gpu.agree("all-zero weights", &spec);
    let mut spec = small("zero");
    spec.mlp.layers.last_mut().unwrap().scales = vec![0.0; 3];
    gpu.agree("a zero scale", &spec);
    let cfg = FixtureConfig {
        layout: Layout::Nbc { channels: 1, bits_coarse_to_fine: vec![2, 2, 2] },
        ..FixtureConfig::ntc("sat", 16, 32, 32, 1)
    };
    let mut spec = generate(&cfg);
    spec.grids.iter_mut().for_each(|g| g.quantization = vec![(i16::MAX, 0)]);
    gpu.agree("fused grids saturating", &spec);
}

/// Random valid materials (`random_config`: 1–70 texels a side, NTC and NBC layouts, 1–8 bits
/// per code, 1–16 channels, 0–3 hidden layers of 1–64 neurons, the Q-formats and LOD codes
/// drawn): shapes the generated kernels pad and layouts their input features are written for.
/// Three seeds, each a few pipelines per kernel to compile (15–30 s on lavapipe): 2 (NTC with
/// its high-resolution grid read twice, LOD code 3, 10 and 12 neurons, 14 channels, 55 × 66
/// clamped), 4 (NBC, three hidden layers of 46, 27 and 39 neurons: the emulated matrix kernel
/// fits three subgroups in lavapipe's workgroup memory, batches of 48 texels that do not divide
/// a tile) and 7 (NBC of three levels, no hidden layer, 14 channels, wrapping).
#[test]
fn random_materials_decode_as_on_the_cpu() {
    let gpu = Gpu::new();
    for seed in [2, 4, 7] {
        let cfg = random_config(seed);
        let spec = generate(&cfg);
        gpu.agree(&format!("random material {seed} ({cfg:?})"), &spec);
    }
}

/// A level whose terms come in an order the NTC and NBC layouts never write
/// (`terms_in_any_order`: `Bilinear[0]`, `Nearest4[1]`, `Nearest4[0]` and a chain of eight
/// grids, `Bilinear[2, 0, 2, 2, 0, 0, 2, 0]`): the generated input features of each kernel and
/// tile entry see two nearest terms, a grid read in both modes in that order and the longest
/// chain the format allows, sharing a grid with them.
#[test]
fn a_level_of_terms_in_any_order_decodes_as_on_the_cpu() {
    let gpu = Gpu::new();
    gpu.agree("a level of terms in any order", &generate(&terms_in_any_order()));
}

/// Cells of 128, 60 and 64 bits (`wide_cells`: 16 channels at 8 bits, 12 at 5, 8 at 8): a
/// cell's codes fill four or two whole 32-bit words, or (60 bits) start mid-word and span two or
/// three. Every kernel and tile entry against the CPU.
#[test]
fn wide_cells_decode_as_on_the_cpu() {
    let gpu = Gpu::new();
    gpu.agree("cells of up to 128 bits", &generate(&wide_cells()));
}

/// A level reading all 16 grids the format allows (`sixteen_grids_in_one_level`: two chains of
/// 8 and two nearest terms): every kernel's generated features and tile entry against the CPU.
#[test]
fn a_level_of_sixteen_grids_decodes_as_on_the_cpu() {
    let gpu = Gpu::new();
    gpu.agree("a level of sixteen grids", &generate(&sixteen_grids_in_one_level()));
}

/// The widest network the format allows (FORMAT.md §5.3): four layers, 128 inputs (an NTC
/// layout of 16 + 16 grid channels, the high-resolution grid read twice, 8 frequencies of the
/// positional encoding), three hidden layers of 128 and 16 channels. The tiled kernels take
/// fewer texels a workgroup; the matrix kernel's staged weights (106 KiB) exceed the workgroup
/// memory most devices offer (lavapipe's included), so there it refuses the network by name and
/// `upload` takes another kernel, or the weights are read from storage
/// (`NMAT_WGPU_MATRIX_WEIGHTS=storage`).
#[test]
fn the_widest_network_decodes_as_on_the_cpu() {
    let gpu = Gpu::new();
    let cfg = FixtureConfig {
        layout: Layout::Ntc { hi_channels: 16, lo_channels: 16, hi_bits: 4, lo_bits: 4 },
        ntc_hi_bilinear: true,
        hidden: vec![128, 128, 128],
        pe_frequencies: 8,
        lod_input: 0,
        ..FixtureConfig::ntc("widest", 17, 40, 24, 16)
    };
    let spec = generate(&cfg);
    assert_eq!(spec.mlp.layers[0].inputs, 128);
    assert_eq!(spec.mlp.layers.len(), 4);
    gpu.agree("the widest network", &spec);
}

/// A 16384² material of 15 mips (`largest_material`, the largest the format allows, its grids
/// shrunk): the positional encoding's phase and the addressing at the
/// largest coordinates. Too large to decode whole on lavapipe: the corners and middles of every
/// mip, coordinates far outside it (wrapping), and a region at mip 0's far corner, through every
/// kernel.
#[test]
fn the_largest_texture_decodes_as_on_the_cpu() {
    let gpu = Gpu::new();
    let spec = largest_material();
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let mut reqs = Vec::new();
    for mip in 0..15u32 {
        let s = 16384i32 >> mip;
        for (x, y) in [(0, 0), (s - 1, s - 1), (s / 3, s / 2 + 1), (s - 2, 1), (-1, s)] {
            reqs.push(TexelRequest { x, y, mip });
        }
    }
    reqs.extend([
        TexelRequest { x: i32::MAX, y: i32::MIN, mip: 0 },
        TexelRequest { x: i32::MIN, y: 16383, mip: 0 },
        TexelRequest { x: 16381, y: i32::MAX, mip: 1 },
    ]);
    let corner = (16384 - 37, 16384 - 5, 37, 5);
    let corner_texels: Vec<TexelRequest> = (16384 - 5..16384)
        .flat_map(|y| (16384 - 37..16384).map(move |x| TexelRequest { x, y, mip: 0 }))
        .collect();
    let cpu = cpu_codes(&m, &reqs, ChannelMask::ALL);
    let cpu_corner = cpu_codes(&m, &corner_texels, ChannelMask::ALL);
    for (ctx, gm) in gpu.uploads("16384²", &m) {
        let kernel = gm.kernel();
        let got = ctx.decode_requests(&gpu.device, &gpu.queue, &gm, &reqs, ChannelMask::ALL);
        assert_eq!(got.unwrap(), cpu, "{kernel:?}: requests");
        let region = ctx
            .submit_region(&gpu.device, &gpu.queue, &gm, 0, corner, ChannelMask::ALL)
            .unwrap()
            .wait(&gpu.device)
            .unwrap();
        assert_eq!(region, cpu_corner, "{kernel:?}: mip 0's far corner");
    }
}

/// The decoder's integer steps, run alone on the GPU over edge and random operands, against
/// their definitions on the CPU: requantization (`Requant::apply`, saturated to i16, §6.6),
/// hardGELU (`hard_gelu_q`), the floor division the BC encoders' least squares and hardGELU
/// take, and the wrap addressing of an index (`rem_euclid`, §6.1). Written after wgpu's OpenGL
/// backend on Mesa 22.3 computed WGSL's signed `%` otherwise (a floor division of a negative
/// multiple one too small, `−264` wrapped into 78 texels as 70): the shaders take no remainder
/// of signed integers since (a unit test asks naga), and this shows it on whatever adapter runs
/// the tests.
#[test]
fn the_decoders_integer_steps_equal_their_definitions_on_the_gpu() {
    use wgpu::util::DeviceExt;
    let (device, queue) = device();
    // The sampling module declares the steps (its material bindings in group 1 go unused).
    let source = format!(
        "{}\n{}",
        nmat_wgpu::SampleBindings { group: 1, first_binding: 0 }.module(),
        "@group(0) @binding(0) var<storage, read> cases: array<array<u32, 8>>;
         @group(0) @binding(1) var<storage, read_write> results: array<vec4<u32>>;
         @compute @workgroup_size(64)
         fn main(@builtin(global_invocation_id) id: vec3<u32>) {
             let i = id.x + 65535u * 64u * id.y;
             if (i >= arrayLength(&cases)) { return; }
             let c = cases[i];
             results[i] = vec4<u32>(
                 bitcast<u32>(nmat_requantize(bitcast<i32>(c[0]), c[1], c[2])),
                 bitcast<u32>(nmat_hard_gelu(bitcast<i32>(c[3]), c[4])),
                 bitcast<u32>(nmat_floor_div(bitcast<i32>(c[5]), bitcast<i32>(c[6]))),
                 nmat_address(bitcast<i32>(c[5]), c[7], false));
         }",
    );
    // [acc, multiplier, shift, z, f, n (also the index to wrap), d, size]
    let mut cases: Vec<[u32; 8]> = Vec::new();
    let mut rng = nmat_tests::generate::Rng::new(44);
    let edges =
        [0, 1, -1, 2, -2, 3, -3, 255, -256, 32767, -32768, 65536, -65537, i32::MAX, i32::MIN];
    let sizes = [1u32, 2, 3, 5, 24, 40, 78, 96, 255, 1000, 16383, 16384];
    for k in 0..400_000usize {
        let r = [rng.next_u64(), rng.next_u64(), rng.next_u64()];
        let edge = |j: u64| edges[(j % edges.len() as u64) as usize];
        let acc = if k % 4 == 0 { edge(r[0]) } else { r[0] as i32 >> (r[0] >> 59) };
        // A multiplier as the format makes them, in [2^30, 2^31) or 0, and any shift of 1..=62.
        let multiplier =
            if r[1].is_multiple_of(17) { 0 } else { (1u32 << 30) | (r[1] >> 34) as u32 };
        let shift = 1 + ((r[1] >> 8) % 62) as u32;
        // hardGELU takes an i16 in any Q-format of 1..=14 fractional bits.
        let z = if k % 4 == 1 {
            edge(r[1] >> 3).clamp(-32768, 32767)
        } else {
            (r[2] >> 48) as i16 as i32
        };
        let f = 1 + ((r[2] >> 8) % 14) as u32;
        // Divisors of both signs; numerators of both signs, a quarter of them exact multiples.
        let d = match (r[2] >> 20) as i32 >> ((r[2] >> 12) % 31) {
            0 => 3,
            -1 => -7, // (i32::MIN / −1 overflows; the shaders never divide so)
            d => d,
        };
        let n = match k % 4 {
            0 => edge(r[2] >> 40).max(i32::MIN + 1),
            1 => ((r[0] >> 40) as i32 >> ((r[0] >> 16) % 31)).wrapping_mul(d),
            _ => (r[0] >> 32) as i32 >> ((r[0] >> 24) % 32),
        };
        let size = sizes[(r[1] >> 40) as usize % sizes.len()];
        cases.push([acc as u32, multiplier, shift, z as u32, f, n as u32, d as u32, size]);
    }
    let words: Vec<u8> = cases.iter().flatten().flat_map(|w| w.to_le_bytes()).collect();
    let input = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: &words,
        usage: wgpu::BufferUsages::STORAGE,
    });
    let output = common::buffer(
        &device,
        16 * cases.len() as u64,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        None,
    );
    let pipeline = common::compute_pipeline(&device, &source, None);
    let entries = [
        wgpu::BindGroupEntry { binding: 0, resource: input.as_entire_binding() },
        wgpu::BindGroupEntry { binding: 1, resource: output.as_entire_binding() },
    ];
    let groups = (cases.len() as u32).div_ceil(64);
    let groups = (groups.min(65535), groups.div_ceil(65535));
    let got = common::run_compute((&device, &queue), &pipeline, &entries, groups, &output);
    let mut wrong = [0usize; 4];
    for (k, case) in cases.iter().enumerate() {
        let [acc, multiplier, shift, z, f, n, d, size] = *case;
        let (acc, z, n, d) = (acc as i32, z as i32, i64::from(n as i32), i64::from(d as i32));
        let requant = nmat_core::Requant { multiplier: multiplier as i32, shift };
        // floor(n / d) by Euclidean division of a positive divisor.
        let floor = if d > 0 { n.div_euclid(d) } else { (-n).div_euclid(-d) };
        let want = [
            requant.apply(acc).clamp(-32768, 32767) as i32,
            i32::from(nmat_core::internals::hard_gelu_q(z as i16, f as u8)),
            floor as i32,
            n.rem_euclid(i64::from(size)) as i32,
        ];
        for (j, &w) in want.iter().enumerate() {
            let at = 16 * k + 4 * j;
            let g = i32::from_le_bytes(got[at..at + 4].try_into().unwrap());
            if g != w {
                if wrong[j] < 3 {
                    eprintln!("step {j} of case {case:?}: the GPU gives {g}, the definition {w}");
                }
                wrong[j] += 1;
            }
        }
    }
    assert_eq!(
        wrong, [0; 4],
        "cases of 400 000 that differ: requantization, hardGELU, floor division, wrap"
    );
}
