//! The core's BC blocks against an independent decoder (`bcdec_rs`, a port of the widely used
//! `bcdec`): every block — any bytes, and every block the encoders write for real images —
//! decodes to the same values with both.

use nmat_core::bc::{
    ALL_VALID, decode_bc1, decode_bc4, decode_bc5, encode_bc1, encode_bc4, encode_bc5, valid_mask,
};

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

fn peer_bc1(block: &[u8; 8]) -> [[u8; 4]; 16] {
    let mut rgba = [0u8; 64];
    bcdec_rs::bc1(block, &mut rgba, 16);
    std::array::from_fn(|i| [rgba[4 * i], rgba[4 * i + 1], rgba[4 * i + 2], rgba[4 * i + 3]])
}

fn peer_bc4(block: &[u8; 8]) -> [u8; 16] {
    let mut out = [0u8; 16];
    bcdec_rs::bc4(block, &mut out, 4, false);
    out
}

fn peer_bc5(block: &[u8; 16]) -> ([u8; 16], [u8; 16]) {
    let mut rg = [0u8; 32];
    bcdec_rs::bc5(block, &mut rg, 8, false);
    (std::array::from_fn(|i| rg[2 * i]), std::array::from_fn(|i| rg[2 * i + 1]))
}

/// Random bytes as blocks, and every endpoint pair of BC4 (both palette modes): the same values.
#[test]
fn any_block_decodes_like_bcdec() {
    let mut rng = Rng(0x00C0_FFEE);
    for _ in 0..200_000 {
        let a = rng.next().to_le_bytes();
        let b = rng.next().to_le_bytes();
        assert_eq!(decode_bc1(&a), peer_bc1(&a), "BC1 {a:02x?}");
        assert_eq!(decode_bc4(&a), peer_bc4(&a), "BC4 {a:02x?}");
        let mut ab = [0u8; 16];
        ab[..8].copy_from_slice(&a);
        ab[8..].copy_from_slice(&b);
        assert_eq!(decode_bc5(&ab), peer_bc5(&ab), "BC5 {ab:02x?}");
    }
    for a0 in 0..=255u8 {
        for a1 in 0..=255u8 {
            let block = [a0, a1, 0x88, 0xC6, 0xFA, 0x88, 0xC6, 0xFA];
            assert_eq!(decode_bc4(&block), peer_bc4(&block), "BC4 endpoints {a0} {a1}");
        }
    }
}

/// A procedural image with gradients, edges and noise, 37×29 (edge blocks partly outside), as
/// RGB; its blocks encoded by the core decode the same with both decoders, and the pixels
/// outside the image do not matter.
#[test]
fn encoded_images_decode_like_bcdec() {
    let (w, h) = (37u32, 29u32);
    let mut rng = Rng(17);
    let pixel = |x: u32, y: u32, rng: &mut Rng| -> [u8; 3] {
        let n = (rng.next() % 19) as i32 - 9;
        let edge = if (x + 2 * y) % 23 < 11 { 90 } else { 0 };
        let c = |v: i32| v.clamp(0, 255) as u8;
        [c(x as i32 * 6 + edge + n), c(200 - y as i32 * 5 + n), c(((x * y) % 256) as i32 / 2 + n)]
    };
    let image: Vec<[u8; 3]> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| pixel(x, y, &mut rng))
        .collect();
    for by in 0..h.div_ceil(4) {
        for bx in 0..w.div_ceil(4) {
            let valid = valid_mask(bx, by, w, h);
            let at = |i: usize| {
                let (x, y) = (4 * bx + i as u32 % 4, 4 * by + i as u32 / 4);
                // Past the edge: something arbitrary (the encoders must ignore it).
                image
                    .get((y * w + x) as usize)
                    .filter(|_| x < w && y < h)
                    .copied()
                    .unwrap_or([7, 7, 7])
            };
            let rgb: [[u8; 3]; 16] = std::array::from_fn(at);
            let (r, g): ([u8; 16], [u8; 16]) =
                (std::array::from_fn(|i| rgb[i][0]), std::array::from_fn(|i| rgb[i][1]));
            let b1 = encode_bc1(&rgb, valid);
            assert_eq!(decode_bc1(&b1), peer_bc1(&b1));
            let b4 = encode_bc4(&r, valid);
            assert_eq!(decode_bc4(&b4), peer_bc4(&b4));
            let b5 = encode_bc5(&r, &g, valid);
            assert_eq!(decode_bc5(&b5), peer_bc5(&b5));
            if valid != ALL_VALID {
                let other: [[u8; 3]; 16] =
                    std::array::from_fn(
                        |i| {
                            if (valid >> i) & 1 != 0 { rgb[i] } else { [250, 3, 128] }
                        },
                    );
                assert_eq!(encode_bc1(&other, valid), b1, "block ({bx}, {by})");
            }
        }
    }
}
