//! CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320, init and final xor 0xFFFFFFFF): the
//! checksum of docs/FORMAT.md §2. Chosen because every platform and tool has it (zlib's `crc32`).

#[allow(clippy::indexing_slicing)] // const evaluation: an out-of-range index fails the build
const TABLES: [[u32; 256]; 8] = {
    let mut t = [[0u32; 256]; 8];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            k += 1;
        }
        t[0][i] = c;
        i += 1;
    }
    // Slicing-by-8 (Intel's method): table k advances a byte by k further zero bytes.
    let mut k = 1;
    while k < 8 {
        let mut i = 0;
        while i < 256 {
            let prev = t[k - 1][i];
            t[k][i] = (prev >> 8) ^ t[0][(prev & 0xFF) as usize];
            i += 1;
        }
        k += 1;
    }
    t
};

fn entry(table: usize, index: u32) -> u32 {
    // `index` is masked to a byte and `table` < 8 at every call site.
    TABLES.get(table).and_then(|t| t.get((index & 0xFF) as usize)).copied().unwrap_or(0)
}

/// Running CRC-32 state.
#[derive(Clone, Copy)]
pub struct Crc32(u32);

impl Crc32 {
    pub const fn new() -> Self {
        Crc32(0xFFFF_FFFF)
    }

    pub fn update(&mut self, bytes: &[u8]) {
        let mut c = self.0;
        let mut chunks = bytes.chunks_exact(8);
        for ch in &mut chunks {
            let v = u64::from_le_bytes(<[u8; 8]>::try_from(ch).unwrap_or([0; 8]));
            let (lo, hi) = (c ^ v as u32, (v >> 32) as u32);
            c = entry(7, lo)
                ^ entry(6, lo >> 8)
                ^ entry(5, lo >> 16)
                ^ entry(4, lo >> 24)
                ^ entry(3, hi)
                ^ entry(2, hi >> 8)
                ^ entry(1, hi >> 16)
                ^ entry(0, hi >> 24);
        }
        for &b in chunks.remainder() {
            c = entry(0, c ^ u32::from(b)) ^ (c >> 8);
        }
        self.0 = c;
    }

    pub const fn finish(self) -> u32 {
        self.0 ^ 0xFFFF_FFFF
    }
}

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

/// The file checksum: CRC-32 of the whole file with the 4 checksum bytes (offset 20) read as zero.
pub fn file_checksum(file: &[u8]) -> u32 {
    let mut crc = Crc32::new();
    crc.update(file.get(..20).unwrap_or(file));
    crc.update(&[0; 4]);
    crc.update(file.get(24..).unwrap_or(&[]));
    crc.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_standard_check_value() {
        // The CRC-32 "check" value from the catalogue of parametrised CRC algorithms.
        let mut c = Crc32::new();
        c.update(b"123456789");
        assert_eq!(c.finish(), 0xCBF4_3926);
    }

    #[test]
    fn slicing_by_8_matches_the_bytewise_definition() {
        let data: [u8; 300] = core::array::from_fn(|i| (i * 7 + 3) as u8);
        for len in 0..data.len() {
            let mut fast = Crc32::new();
            fast.update(&data[..len]);
            let mut slow = Crc32::new();
            for b in &data[..len] {
                slow.update(core::slice::from_ref(b));
            }
            assert_eq!(fast.finish(), slow.finish(), "{len}");
        }
    }
}
