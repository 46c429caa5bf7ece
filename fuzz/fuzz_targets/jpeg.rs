//! Any bytes → `nmat_encode::jpeg::index_jpeg` (as a JPEG file): a typed error or an index, never a
//! panic; an index always makes a valid material (or a typed limit), and its rows decoded through
//! the prepared `Decoder` equal texel-by-texel decodes. JPEG materials given as `.nmat` bytes are
//! decoded by the `decode` target.
#![no_main]
use libfuzzer_sys::fuzz_target;
use nmat_core::{ChannelMask, Container, Decoder, Error};
use nmat_encode::jpeg::{index_jpeg, material_from_jpeg};

/// The rows and columns whose texels are compared: both sides of the first MCU boundaries of 8-
/// and 16-texel MCUs (odd and even rows and columns of 4:2:0 chroma), and the last row or column
/// (the partial MCU at the edge). A single texel decodes its whole MCU, so comparing every texel
/// of a 64 × 64 corner cost milliseconds per input.
fn probes(size: u32) -> impl Iterator<Item = u32> {
    let mut at = [0, 7, 8, 15, 16, size.saturating_sub(1)];
    at.sort_unstable();
    let mut last = None;
    at.into_iter().filter(move |&p| p < size && last.replace(p) != Some(p))
}

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
    // A row span of the first 32 texels at most (two to four MCUs; a small file may declare a
    // 65535² image), on the probed rows; its texels at the probed columns equal single decodes.
    let n = w.min(32) as usize;
    let mut span = vec![0u8; n * 16];
    for y in probes(h).map(i64::from) {
        let total = d.decode_span_u8(&m, 0, y, 0, n, ChannelMask::ALL, &mut span).expect("a row decodes");
        let c = total / n;
        for x in probes(n as u32).map(|x| x as usize) {
            let mut one = [0u8; 16];
            m.decode_texel_u8(x as i64, y, 0, ChannelMask::ALL, &mut one).expect("a texel decodes");
            assert_eq!(span[x * c..(x + 1) * c], one[..c], "texel ({x}, {y})");
        }
    }
});
