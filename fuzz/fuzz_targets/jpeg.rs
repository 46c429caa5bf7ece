//! Any bytes → `nmat_encode::jpeg::index_jpeg` (as a JPEG file): a typed error or an index, never a
//! panic; an index always makes a valid material (or a typed limit), and its rows decoded through
//! the prepared `Decoder` equal texel-by-texel decodes. JPEG materials given as `.nmat` bytes are
//! decoded by the `decode` target.
#![no_main]
use libfuzzer_sys::fuzz_target;
use nmat_core::{ChannelMask, Container, Decoder, Error};
use nmat_encode::jpeg::{index_jpeg, material_from_jpeg};

fuzz_target!(|data: &[u8]| {
    let Ok(indexed) = index_jpeg(data) else { return };
    let bytes = match material_from_jpeg(&indexed, "fuzz.png").to_bytes() {
        Ok(bytes) => bytes,
        Err(Error::LimitExceeded { .. }) => return,
        Err(e) => panic!("an indexed JPEG makes an invalid material: {e}"),
    };
    let m = Container::parse(&bytes).expect("an indexed JPEG material parses");
    let d = Decoder::new(&m);
    let (w, h) = m.mip_size(0);
    // The first 64 × 64 texels at most: a small file may declare a 65535² image.
    let n = w.min(64) as usize;
    let mut span = vec![0u8; n * 16];
    for y in 0..i64::from(h.min(64)) {
        let total = d.decode_span_u8(&m, 0, y, 0, n, ChannelMask::ALL, &mut span).expect("a row decodes");
        let c = total / n;
        for x in 0..n {
            let mut one = [0u8; 16];
            m.decode_texel_u8(x as i64, y, 0, ChannelMask::ALL, &mut one).expect("a texel decodes");
            assert_eq!(span[x * c..(x + 1) * c], one[..c]);
        }
    }
});
