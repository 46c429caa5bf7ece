//! CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320, init and final xor 0xFFFFFFFF): the
//! checksum of docs/FORMAT.md §2. Chosen because every platform and tool has it (zlib's `crc32`).

#[allow(clippy::indexing_slicing)] // const evaluation: an out-of-range index fails the build
const TABLE: [u32; 256] = {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
};

/// Running CRC-32 state.
#[derive(Clone, Copy)]
pub struct Crc32(u32);

impl Crc32 {
    pub const fn new() -> Self {
        Crc32(0xFFFF_FFFF)
    }

    pub fn update(&mut self, bytes: &[u8]) {
        let mut c = self.0;
        for &b in bytes {
            let idx = ((c ^ u32::from(b)) & 0xFF) as u8;
            // `idx` is a u8, the table has 256 entries.
            c = TABLE.get(usize::from(idx)).copied().unwrap_or(0) ^ (c >> 8);
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
}
