use nmat_core::{ChannelMask, Container};
use nmat_tests::generate::{generate, golden_configs};
use nmat_tests::texels;
fn main() {
    let cfg = &golden_configs()[5];
    let spec = generate(cfg);
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let (mut c, mut u) = ([0u8; 16], [0f32; 16]);
    for (x, y, mip) in texels(&m) {
        m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut c).unwrap();
        m.decode_texel_unit(x, y, mip, ChannelMask::ALL, &mut u).unwrap();
        for k in 0..3 { let d = c[k] as f32 - (u[k]*255.0).round(); if d.abs() > 1.0 { println!("{x} {y} {mip} ch{k} int {} float {}", c[k], u[k]*255.0); } }
    }
}
