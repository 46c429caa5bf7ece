//! Reading the entropy-coded data of an indexed JPEG stream (docs/FORMAT.md §11.3): a bit reader
//! that starts at any bit, canonical Huffman tables, and one block's coefficients. Decoding is
//! total: a code no table holds decodes as symbol 0, bits past the end read as 0, and a run past
//! the last coefficient ends the block, so hostile data cannot fail or panic here.

use crate::bytes::u8_at;

/// Natural (row-major) position of the k-th coefficient in zigzag order (ITU T.81 figure A.6).
pub(crate) const ZIGZAG: [u8; 64] = [
    0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5, 12, 19, 26, 33, 40, 48, 41, 34, 27, 20,
    13, 6, 7, 14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51, 58, 59,
    52, 45, 38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63,
];

/// Bits of `data`, most significant first, from bit `pos`.
pub(crate) struct Bits<'a> {
    pub data: &'a [u8],
    pub pos: u64,
}

impl Bits<'_> {
    /// The next 16 bits without consuming them.
    #[inline(always)]
    fn peek16(&self) -> u32 {
        let byte = usize::try_from(self.pos >> 3).unwrap_or(usize::MAX);
        let b = |k: usize| u32::from(u8_at(self.data, byte.saturating_add(k)));
        let word = (b(0) << 16) | (b(1) << 8) | b(2);
        (word >> (8 - (self.pos & 7) as u32)) & 0xFFFF
    }

    /// The next `n ≤ 16` bits as an unsigned number.
    #[inline(always)]
    pub fn take(&mut self, n: u32) -> u32 {
        if n == 0 {
            return 0;
        }
        let v = self.peek16() >> (16 - n.min(16));
        self.pos = self.pos.wrapping_add(u64::from(n));
        v
    }
}

/// The canonical decoding tables of a Huffman table whose codes of length 1 ..= 16 number
/// `counts` (ITU T.81 F.2.2.3): for each length `l`, the largest code of that length (−1: none)
/// and what to add to a code of that length to get its symbol's index in the table's values.
pub fn huffman_decoding(counts: &[u8; 16]) -> ([i32; 17], [i32; 17]) {
    let mut maxcode = [-1i32; 17];
    let mut offset = [0i32; 17];
    let (mut code, mut k) = (0i32, 0i32);
    for (l, &n) in (1..=16).zip(counts) {
        let n = i32::from(n);
        if let (Some(m), Some(o)) = (maxcode.get_mut(l), offset.get_mut(l)) {
            *o = k - code;
            if n > 0 {
                *m = code + n - 1;
            }
        }
        code = (code + n) << 1;
        k += n;
    }
    (maxcode, offset)
}

/// A Huffman table (the counts of codes of each length 1..=16 and the symbols in code order, as
/// in a JPEG DHT segment), ready to decode.
pub(crate) struct Huffman<'a> {
    /// Largest code of each length (−1: none), left-aligned to 16 bits as `(code + 1) << (16 − l) − 1`
    /// is compared with the next 16 bits.
    maxcode: [i32; 17],
    /// Index of the symbol of code `c` of length `l`: `c + offset[l]`.
    offset: [i32; 17],
    values: &'a [u8],
}

impl<'a> Huffman<'a> {
    pub fn new(counts: &[u8; 16], values: &'a [u8]) -> Huffman<'a> {
        let (maxcode, offset) = huffman_decoding(counts);
        Huffman { maxcode, offset, values }
    }

    #[inline(always)]
    pub fn decode(&self, bits: &mut Bits<'_>) -> u8 {
        let word = bits.peek16() as i32;
        for l in 1..=16u32 {
            let code = word >> (16 - l);
            let max = self.maxcode.get(l as usize).copied().unwrap_or(-1);
            if code <= max {
                bits.pos = bits.pos.wrapping_add(u64::from(l));
                let at = code + self.offset.get(l as usize).copied().unwrap_or(0);
                return usize::try_from(at).ok().map_or(0, |i| u8_at(self.values, i));
            }
        }
        bits.pos = bits.pos.wrapping_add(16);
        0
    }
}

/// The signed value of `n` extra bits `v` (ITU T.81 F.2.2.1, EXTEND).
#[inline(always)]
pub(crate) fn extend(v: u32, n: u32) -> i32 {
    if n == 0 {
        0
    } else if v < (1 << (n - 1)) {
        v as i32 - (1 << n) + 1
    } else {
        v as i32
    }
}

/// Reads one block: returns the DC difference it codes, and writes the dequantized AC
/// coefficients (`coefs[ZIGZAG[k]] = value · quant[k]`, k ≥ 1) over zeros; the caller sets the DC.
#[inline(always)]
pub(crate) fn block(
    bits: &mut Bits<'_>,
    dc: &Huffman<'_>,
    ac: &Huffman<'_>,
    quant: &[u8],
    coefs: &mut [i32; 64],
) -> i32 {
    *coefs = [0; 64];
    let s = u32::from(dc.decode(bits)).min(16);
    let diff = extend(bits.take(s), s);
    let mut k = 1usize;
    while k < 64 {
        let rs = ac.decode(bits);
        let (run, size) = (usize::from(rs >> 4), u32::from(rs & 15));
        if size == 0 {
            if run != 15 {
                break;
            }
            k += 16;
            continue;
        }
        k += run;
        let v = extend(bits.take(size), size);
        if let (Some(&z), Some(&q)) = (ZIGZAG.get(k), quant.get(k))
            && let Some(c) = coefs.get_mut(usize::from(z))
        {
            *c = v.wrapping_mul(i32::from(q));
        }
        k += 1;
    }
    diff
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zigzag_is_a_permutation_walking_the_antidiagonals() {
        let mut seen = [false; 64];
        for (k, &z) in ZIGZAG.iter().enumerate() {
            assert!(!seen[z as usize]);
            seen[z as usize] = true;
            if k > 0 {
                let (r0, c0) = (ZIGZAG[k - 1] / 8, ZIGZAG[k - 1] % 8);
                let (r1, c1) = (z / 8, z % 8);
                // Each step moves to a neighbouring cell (one step along a row, column or diagonal).
                assert!(r0.abs_diff(r1) <= 1 && c0.abs_diff(c1) <= 1, "step {k}");
            }
        }
    }

    #[test]
    fn canonical_codes_decode_to_their_symbols() {
        // Lengths: two codes of 2 bits (00, 01), one of 3 (100), one of 4 (1010).
        let mut counts = [0u8; 16];
        counts[1] = 2;
        counts[2] = 1;
        counts[3] = 1;
        let values = [7u8, 3, 9, 5];
        let table = Huffman::new(&counts, &values);
        // 00 | 01 | 100 | 1010 | 1111 1111 1111 1111 (no code): 7 3 9 5 then 0.
        let data = [0b0001_1001, 0b0101_1111, 0xFF, 0xFF, 0xF0];
        let mut bits = Bits { data: &data, pos: 0 };
        let got: [u8; 5] = core::array::from_fn(|_| table.decode(&mut bits));
        assert_eq!(got, [7, 3, 9, 5, 0]);
        assert_eq!(bits.pos, 2 + 2 + 3 + 4 + 16);
    }

    #[test]
    fn extend_matches_the_standard_table() {
        assert_eq!(extend(0, 1), -1);
        assert_eq!(extend(1, 1), 1);
        assert_eq!(extend(0, 3), -7);
        assert_eq!(extend(3, 3), -4);
        assert_eq!(extend(4, 3), 4);
        assert_eq!(extend(2047, 11), 2047);
        assert_eq!(extend(0, 11), -2047);
    }

    #[test]
    fn bits_past_the_end_read_as_zero() {
        let data = [0xFFu8];
        let mut bits = Bits { data: &data, pos: 4 };
        assert_eq!(bits.take(8), 0xF0);
        assert_eq!(bits.take(16), 0);
        let mut far = Bits { data: &data, pos: u64::MAX - 3 };
        assert_eq!(far.take(16), 0);
    }
}
