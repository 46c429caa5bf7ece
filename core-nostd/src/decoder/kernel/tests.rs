//! Every SIMD kernel this CPU runs against the scalar twin, through the one dispatch site.

use alloc::vec::Vec;
use core::ops::Range;

use super::*;
use crate::decoder::packed::Parts;
use crate::neural::mlp::{Activation, Requant};

/// Whether this AArch64 CPU has the dot-product extension, asked the way the kernel choice does
/// not (the auxiliary vector through std, or the build's target features without it).
fn cpu_has_dotprod() -> bool {
    #[cfg(all(target_arch = "aarch64", feature = "std"))]
    {
        extern crate std;
        std::arch::is_aarch64_feature_detected!("dotprod")
    }
    #[cfg(not(all(target_arch = "aarch64", feature = "std")))]
    {
        cfg!(all(target_arch = "aarch64", target_feature = "dotprod"))
    }
}

/// The SIMD kernels this CPU runs. On AArch64 NEON must be among them, and the dot-product kernel
/// where the CPU has the extension: the tests below would otherwise compare nothing there.
fn simd_kernels() -> Vec<Available> {
    let kernels: Vec<Available> = Kernel::ALL
        .into_iter()
        .filter(|&k| k != Kernel::Scalar)
        .filter_map(Available::new)
        .collect();
    if cfg!(target_arch = "aarch64") {
        assert!(kernels.iter().any(|k| k.kernel() == Kernel::Neon), "NEON not available");
        let dot = kernels.iter().any(|k| k.kernel() == Kernel::NeonDot);
        assert_eq!(dot, cpu_has_dotprod(), "the dot-product kernel's availability");
    }
    kernels
}

/// One layer through a kernel.
struct Layer<'l> {
    l: &'l PackedLayer,
    x: &'l [i16; MAX_WIDTH],
    y: &'l mut [i16; MAX_WIDTH],
    blocks: u32,
}

impl Job for Layer<'_> {
    type Output = ();
    #[inline(always)]
    fn run<K: Layers>(self, kernel: K) {
        kernel.forward(self.l, self.x, self.y, self.blocks);
    }
}

/// One layer for a group of texels through a kernel.
struct Group<'l> {
    l: &'l PackedLayer,
    xs: &'l [[i16; MAX_WIDTH]; GROUP],
    init: [&'l [i32]; GROUP],
    pairs: Range<usize>,
    ys: &'l mut [[i16; MAX_WIDTH]; GROUP],
    blocks: u32,
}

impl Job for Group<'_> {
    type Output = ();
    #[inline(always)]
    fn run<K: Layers>(self, kernel: K) {
        let (l, xs, init, pairs, ys, blocks) =
            (self.l, self.xs, self.init, self.pairs, self.ys, self.blocks);
        kernel.forward_group(l, xs, init, pairs, ys, blocks, GROUP);
    }
}

/// A layer's sums over a range of pairs through a kernel.
struct Sums<'l> {
    l: &'l PackedLayer,
    x: &'l [i16; MAX_WIDTH],
    pairs: Range<usize>,
    sums: &'l mut [i32; MAX_WIDTH],
}

impl Job for Sums<'_> {
    type Output = ();
    #[inline(always)]
    fn run<K: Layers>(self, kernel: K) {
        kernel.sums(self.l, self.x, self.pairs, self.sums);
    }
}

/// Which kernel's code a job ran in.
struct Which;

impl Job for Which {
    type Output = Kernel;
    #[inline(always)]
    fn run<K: Layers>(self, _kernel: K) -> Kernel {
        K::KERNEL
    }
}

/// `run` runs the code of the kernel it is given — on AArch64 the NEON kernels', the best there
/// (the dot-product one where the CPU has the extension): a build where a NEON path were silently
/// not taken fails here.
#[test]
fn the_dispatch_runs_the_kernel_it_is_given() {
    for kernel in Kernel::ALL {
        if let Some(available) = Available::new(kernel) {
            assert_eq!(run(available, Which), kernel);
        }
    }
    assert_eq!(run(Available::best(), Which), Kernel::best());
    if cfg!(target_arch = "aarch64") {
        let best = if cpu_has_dotprod() { Kernel::NeonDot } else { Kernel::Neon };
        assert_eq!(Kernel::best(), best);
    }
    for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
        // The probe's value depends on its products, so on how many rounds ran.
        let value = |rounds| kernel.probe(rounds).unwrap();
        let (one, two, three) = (value(1), value(2), value(3));
        assert!(one != two && two != three && one != three, "{kernel:?} probe {one} {two} {three}");
    }
    for kernel in Kernel::ALL.into_iter().filter(|k| !k.is_available()) {
        assert_eq!(kernel.probe(1), None, "{kernel:?}");
    }
}

/// The names `span_profile` and the docs use (docs/PERFORMANCE.md), one per kernel; the products
/// of a probe round follow the probes' code (the scalar one's 8 chains of one multiply-add) and
/// the instructions' widths (AVX-512 twice AVX2's lanes, `sdot` twice `smlal`'s products).
#[test]
fn kernels_have_their_names_and_widths() {
    let names = Kernel::ALL.map(Kernel::name);
    assert_eq!(names, ["scalar", "neon", "neon-dotprod", "avx2", "avx512-vnni"]);
    let macs = |k: Kernel| k.probe_macs_per_round();
    assert_eq!(macs(Kernel::Scalar), 8);
    assert_eq!(macs(Kernel::Avx512Vnni), 2 * macs(Kernel::Avx2));
    assert_eq!(macs(Kernel::NeonDot), 2 * macs(Kernel::Neon));
    assert!(Kernel::ALL.into_iter().skip(1).all(|k| macs(k) > 8));
}

/// On x86-64 Linux the kernels available are those whose instructions `/proc/cpuinfo` lists
/// (asked the way the kernel choice does not), and [`Kernel::best`] is the fastest of them: a
/// CPU check that said no would leave every test above comparing the scalar kernel with itself.
#[cfg(all(target_arch = "x86_64", target_os = "linux", feature = "std"))]
#[test]
fn x86_kernels_are_those_the_cpu_lists() {
    extern crate std;
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap();
    let flags: Vec<&str> =
        info.lines().find(|l| l.starts_with("flags")).unwrap().split_whitespace().collect();
    let has = |flag: &str| flags.contains(&flag);
    let vnni = has("avx512f") && has("avx512bw") && has("avx512_vnni");
    assert!(Kernel::Scalar.is_available());
    assert_eq!(Kernel::Avx2.is_available(), has("avx2"));
    assert_eq!(Kernel::Avx512Vnni.is_available(), vnni);
    assert!(!Kernel::Neon.is_available() && !Kernel::NeonDot.is_available());
    let best = if vnni {
        Kernel::Avx512Vnni
    } else if has("avx2") {
        Kernel::Avx2
    } else {
        Kernel::Scalar
    };
    assert_eq!(Kernel::best(), best);
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn range(&mut self, lo: i64, hi: i64) -> i64 {
        lo + (self.next() % (hi - lo + 1) as u64) as i64
    }
    /// Mostly uniform, sometimes a bound: extremes are where shortcuts break.
    fn edgy(&mut self, lo: i64, hi: i64) -> i64 {
        match self.next() % 8 {
            0 => lo,
            1 => hi,
            2 => self.range(-2, 2).clamp(lo, hi),
            _ => self.range(lo, hi),
        }
    }
    fn activation(&mut self) -> Activation {
        if self.next().is_multiple_of(2) { Activation::None } else { Activation::HardGelu }
    }
}

/// A random requantization: sometimes a zero scale, else any multiplier and shift.
fn requant(rng: &mut Rng) -> Requant {
    if rng.next().is_multiple_of(6) {
        return Requant { multiplier: 0, shift: 1 };
    }
    Requant {
        multiplier: rng.edgy(1 << 30, i64::from(i32::MAX)) as i32,
        shift: rng.edgy(1, 62) as u32,
    }
}

fn layer(rng: &mut Rng, inputs: usize, outputs: usize) -> PackedLayer {
    let weights: Vec<i8> = (0..inputs * outputs).map(|_| rng.edgy(-128, 127) as i8).collect();
    let bias: Vec<i32> = (0..outputs).map(|_| rng.edgy(-(1 << 30), 1 << 30) as i32).collect();
    let requant: Vec<Requant> = (0..outputs).map(|_| requant(rng)).collect();
    let parts = Parts {
        inputs,
        outputs,
        weights: &weights,
        bias: &bias,
        requant: &requant,
        out_frac_bits: rng.edgy(1, 14) as u8,
        activation: rng.activation(),
    };
    PackedLayer::from_parts(&parts).expect("parts within the limits")
}

/// The checked constructor refuses parts that break the layout's invariants.
#[test]
fn from_parts_refuses_what_breaks_the_invariants() {
    let w = [1i8; 4];
    let ok = Requant { multiplier: 1 << 30, shift: 20 };
    let good = Parts {
        inputs: 2,
        outputs: 2,
        weights: &w,
        bias: &[0, 0],
        requant: &[ok, ok],
        out_frac_bits: 8,
        activation: Activation::None,
    };
    assert!(PackedLayer::from_parts(&good).is_some());
    let bad_requants = [
        Requant { multiplier: 1 << 29, shift: 20 },
        Requant { multiplier: -1, shift: 20 },
        Requant { multiplier: 1 << 30, shift: 0 },
        Requant { multiplier: 1 << 30, shift: 63 },
    ];
    for bad in bad_requants {
        let requant = [ok, bad];
        assert!(PackedLayer::from_parts(&Parts { requant: &requant, ..good }).is_none(), "{bad:?}");
    }
    assert!(PackedLayer::from_parts(&Parts { weights: &w[..3], ..good }).is_none());
    assert!(PackedLayer::from_parts(&Parts { bias: &[0], ..good }).is_none());
    assert!(PackedLayer::from_parts(&Parts { out_frac_bits: 0, ..good }).is_none());
    assert!(PackedLayer::from_parts(&Parts { out_frac_bits: 15, ..good }).is_none());
    let wide = alloc::vec![0i8; 2 * (MAX_WIDTH + 1)];
    let too_wide = Parts { inputs: MAX_WIDTH + 1, weights: &wide, ..good };
    assert!(PackedLayer::from_parts(&too_wide).is_none());
}

/// Every SIMD layer this CPU runs against the scalar twin on random layers of every shape class
/// (one block, 4-block runs plus a remainder, odd input counts) with extreme weights, inputs,
/// biases, multipliers and shifts, and every block selection; per texel and in groups.
#[test]
fn simd_layers_match_the_scalar_twin() {
    let kernels = simd_kernels();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    for trial in 0..4000 {
        let inputs = rng.range(1, MAX_WIDTH as i64) as usize;
        let outputs = rng.range(1, MAX_WIDTH as i64) as usize;
        let l = layer(&mut rng, inputs, outputs);
        let (in_pairs, out_pad) = (l.in_pairs(), l.out_pad());
        let mut x = [0i16; MAX_WIDTH];
        for v in x.iter_mut().take(2 * in_pairs) {
            *v = rng.edgy(i64::from(i16::MIN), i64::from(i16::MAX)) as i16;
        }
        let blocks = if trial % 3 == 0 { rng.next() as u32 } else { u32::MAX };
        let mut scalar = [7i16; MAX_WIDTH];
        l.forward_scalar_from(&x, l.bias(), 0..in_pairs, &mut scalar, blocks);
        // The group forms: texel 2 is `x` from the bias; in even trials the others start from
        // random rows, and all sum a random number of pairs.
        let mut xs = [[0i16; MAX_WIDTH]; GROUP];
        let starts: Vec<Vec<i32>> = (0..GROUP)
            .map(|_| (0..out_pad).map(|_| rng.edgy(-(1 << 30), 1 << 30) as i32).collect())
            .collect();
        let mut init = [l.bias(); GROUP];
        for (t, v) in xs.iter_mut().enumerate() {
            for (i, slot) in v.iter_mut().enumerate().take(2 * in_pairs) {
                *slot = if t == 2 { x[i] } else { rng.edgy(-32768, 32767) as i16 };
            }
            if t != 2 && trial % 2 == 0 {
                init[t] = &starts[t];
            }
        }
        // Even trials: a random range of pairs, from the first one in a quarter of them.
        let pairs = if trial % 2 == 0 {
            let end = rng.range(0, in_pairs as i64) as usize;
            let start = if trial % 8 == 0 { 0 } else { rng.range(0, end as i64) as usize };
            start..end
        } else {
            0..in_pairs
        };
        let selected = |b: usize| blocks & (1 << b) != 0;
        // The layer split at a pair: the bias plus the sums over the pairs before it, then the
        // pairs from it on, is the whole layer (integer sums do not depend on their order).
        let split = pairs.end.min(in_pairs);
        let mut init_split = [0i32; MAX_WIDTH];
        l.pair_sums(&x, 0..split, &mut init_split);
        for (s, &b) in init_split.iter_mut().zip(l.bias()) {
            *s = s.wrapping_add(b);
        }
        let mut resumed = [7i16; MAX_WIDTH];
        l.forward_scalar_from(&x, &init_split, split..in_pairs, &mut resumed, blocks);
        for b in (0..out_pad / 8).filter(|&b| selected(b)) {
            let rows = 8 * b..8 * b + 8;
            assert_eq!(resumed[rows.clone()], scalar[rows], "split at pair {split}, trial {trial}");
        }
        for &kernel in &kernels {
            let name = kernel.kernel();
            let mut ys = [[7i16; MAX_WIDTH]; GROUP];
            run(kernel, Group { l: &l, xs: &xs, init, pairs: pairs.clone(), ys: &mut ys, blocks });
            for (t, (xt, yt)) in xs.iter().zip(&ys).enumerate() {
                let mut want = [7i16; MAX_WIDTH];
                l.forward_scalar_from(xt, init[t], pairs.clone(), &mut want, blocks);
                if t == 2 && pairs == (0..in_pairs) {
                    assert_eq!(want, scalar, "the scalar forms differ, trial {trial}");
                }
                for b in (0..out_pad / 8).filter(|&b| selected(b)) {
                    let rows = 8 * b..8 * b + 8;
                    assert_eq!(
                        yt[rows.clone()],
                        want[rows],
                        "{name:?} group texel {t} trial {trial}"
                    );
                }
            }
            let mut sums = [7i32; MAX_WIDTH];
            run(kernel, Sums { l: &l, x: &x, pairs: pairs.clone(), sums: &mut sums });
            let mut want = [7i32; MAX_WIDTH];
            l.pair_sums(&x, pairs.clone(), &mut want);
            assert_eq!(sums[..out_pad], want[..out_pad], "{name:?} sums, trial {trial}");
            let mut simd = [7i16; MAX_WIDTH];
            run(kernel, Layer { l: &l, x: &x, y: &mut simd, blocks });
            for b in (0..out_pad / 8).filter(|&b| selected(b)) {
                let rows = 8 * b..8 * b + 8;
                assert_eq!(simd[rows.clone()], scalar[rows], "{name:?} trial {trial}");
            }
        }
    }
}

/// Requantization alone over a dense sweep of shifts and accumulators near every power of two.
#[test]
fn simd_requantization_matches_the_scalar_twin_at_every_shift() {
    let kernels = simd_kernels();
    let mut rng = Rng(42);
    let weights = [0i8; 8];
    for shift in 1..=62u32 {
        for activation in [Activation::None, Activation::HardGelu] {
            let requant: Vec<Requant> = (0..8)
                .map(|_| Requant {
                    multiplier: rng.edgy(1 << 30, i64::from(i32::MAX)) as i32,
                    shift,
                })
                .collect();
            let out_frac_bits = rng.edgy(1, 14) as u8;
            for _ in 0..64 {
                let bias: Vec<i32> = (0..8)
                    .map(|_| {
                        let e = rng.range(0, 31) as u32;
                        let v = (rng.range(-1, 1) << e) + rng.range(-1, 1);
                        v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
                    })
                    .collect();
                let parts = Parts {
                    inputs: 1,
                    outputs: 8,
                    weights: &weights,
                    bias: &bias,
                    requant: &requant,
                    out_frac_bits,
                    activation,
                };
                let l = PackedLayer::from_parts(&parts).expect("parts within the limits");
                let x = [0i16; MAX_WIDTH];
                let mut scalar = [0i16; MAX_WIDTH];
                l.forward_scalar_from(&x, l.bias(), 0..l.in_pairs(), &mut scalar, 1);
                for &kernel in &kernels {
                    let mut simd = [0i16; MAX_WIDTH];
                    run(kernel, Layer { l: &l, x: &x, y: &mut simd, blocks: 1 });
                    assert_eq!(
                        simd[..8],
                        scalar[..8],
                        "{:?} shift {shift}, bias {bias:?}",
                        kernel.kernel()
                    );
                }
            }
        }
    }
}
