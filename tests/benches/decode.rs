//! Per-texel decode cost on one thread: float vs integer, all channels vs one, and the filters.
//! `cargo bench -p nmat-tests --bench decode`. The numbers go to the issue notes and, with the
//! performance issue, to docs/PERFORMANCE.md; tests never assert them.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nmat_core::{ChannelMask, Container, Decoder, Filter, Kernel, Precision, SampleRequest};
use nmat_tests::generate::{generate, golden_configs};
use std::hint::black_box;

fn texel_decoding(c: &mut Criterion) {
    for name in ["ntc_rgb_64", "ntc_pbr10_96x80_clamp", "nbc_8421_64"] {
        let cfg = golden_configs().into_iter().find(|c| c.name == name).expect("golden fixture");
        let bytes = generate(&cfg).to_bytes().expect("valid");
        let m = Container::parse(&bytes).expect("valid");
        let macs = m.neural().expect("a neural material").mlp().macs_per_texel();
        let mut group = c.benchmark_group(format!("{name} ({macs} MACs/texel)"));
        let (w, h) = (i64::from(m.width()), i64::from(m.height()));
        let mut i = 0i64;
        let mut next = move || {
            i = (i + 7919) % (w * h);
            (i % w, i / w)
        };
        group.bench_function("integer u8, all channels", |b| {
            let mut out = [0u8; 16];
            b.iter(|| {
                let (x, y) = next();
                m.decode_texel_u8(x, y, 0, ChannelMask::ALL, &mut out).expect("valid");
                black_box(out)
            })
        });
        group.bench_function("integer u8, channel 0", |b| {
            let mut out = [0u8; 16];
            b.iter(|| {
                let (x, y) = next();
                m.decode_texel_u8(x, y, 0, ChannelMask::single(0), &mut out).expect("valid");
                black_box(out)
            })
        });
        group.bench_function("float f32 (dequantized at use), all channels", |b| {
            let mut out = [0f32; 16];
            b.iter(|| {
                let (x, y) = next();
                m.decode_texel(x, y, 0, ChannelMask::ALL, &mut out).expect("valid");
                black_box(out)
            })
        });
        for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
            let d = Decoder::with_kernel(&m, kernel).expect("available");
            let name = kernel.name();
            group.bench_function(format!("decoder {name} u8 texel, all channels"), |b| {
                let mut out = [0u8; 16];
                b.iter(|| {
                    let (x, y) = next();
                    d.decode_texel_u8(&m, x, y, 0, ChannelMask::ALL, &mut out).expect("valid");
                    black_box(out)
                })
            });
            const SPAN: usize = 64;
            group.throughput(Throughput::Elements(SPAN as u64));
            group.bench_function(format!("decoder {name} u8 span of {SPAN}, all channels"), |b| {
                let mut out = vec![0u8; SPAN * m.channel_count()];
                b.iter(|| {
                    let (_, y) = next();
                    d.decode_span_u8(&m, 0, y, 0, SPAN, ChannelMask::ALL, &mut out).expect("valid");
                    black_box(out.first().copied())
                })
            });
            group.throughput(Throughput::Elements(1));
        }
        let d = Decoder::new(&m);
        group.bench_function("decoder float f32 texel, all channels", |b| {
            let mut out = [0f32; 16];
            b.iter(|| {
                let (x, y) = next();
                d.decode_texel(&m, x, y, 0, ChannelMask::ALL, &mut out).expect("valid");
                black_box(out)
            })
        });
        for filter in [Filter::Stochastic, Filter::Trilinear] {
            group.bench_function(format!("sample {filter:?}, integer"), |b| {
                let mut out = [0f32; 16];
                let mut k = 0u32;
                b.iter(|| {
                    k = k.wrapping_add(1);
                    let u = (k % 997) as f32 / 997.0;
                    let req = SampleRequest {
                        u,
                        v: 1.0 - u,
                        lod: 0.4,
                        filter,
                        precision: Precision::Integer,
                        random: [u, 0.5, 0.25],
                        channels: ChannelMask::ALL,
                    };
                    m.sample(&req, &mut out).expect("valid");
                    black_box(out)
                })
            });
        }
        group.bench_function("parse (with checksum)", |b| {
            b.iter(|| black_box(Container::parse(black_box(&bytes)).is_ok()))
        });
        group.finish();
    }
}

criterion_group!(benches, texel_decoding);
criterion_main!(benches);
