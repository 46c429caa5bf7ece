//! Reading `.nmat` files without trusting them.

use std::path::Path;

/// A .nmat file as read: its fixed-rate bytes (what `Container::parse` reads; a packed file's
/// latents decoded), and what the file on disk was.
pub struct Loaded {
    fixed: Vec<u8>,
    /// The file as stored.
    pub stored: Stored,
}

/// Length and format minor version of a file as stored (a packed file's, before unpacking).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stored {
    pub len: usize,
    pub minor: u16,
    /// Its latents are entropy-coded (docs/FORMAT.md §12).
    pub packed: bool,
}

impl Stored {
    /// What `bytes` (a whole file as read) say of themselves; `packed` if they unpack.
    pub fn of(bytes: &[u8], packed: bool) -> Stored {
        let minor = bytes.get(6..8).map_or(0, |m| u16::from_le_bytes([m[0], m[1]]));
        Stored { len: bytes.len(), minor, packed }
    }

    /// A fixed-rate file of `m`.
    pub fn fixed(m: &nmat_core::Material<'_>) -> Stored {
        Stored { len: m.file_len(), minor: m.version_minor(), packed: false }
    }
}

impl std::ops::Deref for Loaded {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        &self.fixed
    }
}

/// Reads a .nmat file without trusting it ([`read_raw`]) and unpacks it if its latents are
/// entropy-coded (checksum verified), so that the result parses.
pub fn read_nmat(path: &Path) -> Result<Loaded, String> {
    let bytes = read_raw(path)?;
    // A file whose header or table is broken is not packed: parsing it names what is wrong.
    let packed = nmat_core::unpacked_len(&bytes).ok().flatten().is_some();
    let stored = Stored::of(&bytes, packed);
    let fixed = if packed {
        nmat_core::unpack(&bytes, nmat_core::ParseOptions::default())
            .map_err(|e| format!("{}: {e}", path.display()))?
            .into_owned()
    } else {
        bytes
    };
    Ok(Loaded { fixed, stored })
}

/// Reads a .nmat file's bytes as stored without trusting it: only a regular file (opened as
/// every input is, by [`nmat_encode::input::open_regular`]), whose first bytes carry the magic,
/// read no further than the length its header declares (≤ 4 GiB by the format), so a huge or
/// endless input is refused before it is read.
pub fn read_raw(path: &Path) -> Result<Vec<u8>, String> {
    use std::io::Read as _;
    let shown = path.display();
    let (mut file, len) = nmat_encode::input::open_regular(path).map_err(|e| e.to_string())?;
    let mut head = Vec::with_capacity(HEAD);
    file.by_ref().take(HEAD as u64).read_to_end(&mut head).map_err(|e| format!("{shown}: {e}"))?;
    let declared = check_head(&head, len).map_err(|e| format!("{shown}: {e}"))?;
    // The rest, from the same handle: never more than the header declares.
    let mut bytes = head;
    let rest = declared.saturating_sub(bytes.len() as u64);
    file.take(rest).read_to_end(&mut bytes).map_err(|e| format!("{shown}: {e}"))?;
    Ok(bytes)
}

/// Bytes of the header that say what the file is: magic, versions, flags, declared length
/// (docs/FORMAT.md §2).
pub const HEAD: usize = 16;

/// Checks the first [`HEAD`] bytes of a file of `file_len` bytes; returns how many bytes to read
/// (the declared length, or less if the file is shorter: the parser then names the truncation).
pub fn check_head(head: &[u8], file_len: u64) -> Result<u64, String> {
    if !head.starts_with(&nmat_core::MAGIC) {
        return Err(format!("not a .nmat file ({})", signature(head)));
    }
    let declared = head
        .get(12..16)
        .map_or(file_len, |d| u64::from(u32::from_le_bytes(d.try_into().unwrap_or_default())));
    if file_len > declared {
        return Err(format!(
            "{} trailing bytes after the {declared} bytes the header declares (something was \
             appended to the file?)",
            file_len - declared
        ));
    }
    Ok(declared.min(file_len))
}

/// What a file that is not .nmat seems to be, from its first bytes.
fn signature(head: &[u8]) -> String {
    let known: [(&[u8], &str); 9] = [
        (b"\x89PNG", "PNG"),
        (b"\xFF\xD8\xFF", "JPEG"),
        (b"GIF8", "GIF"),
        (b"II*\0", "TIFF"),
        (b"MM\0*", "TIFF"),
        (b"\xABKTX", "KTX"),
        (b"DDS ", "DDS"),
        (b"BM", "BMP"),
        (b"\0\0\0\x0cjXL", "JPEG XL"),
    ];
    if head.is_empty() {
        return "the file is empty".into();
    }
    if head.starts_with(b"RIFF") && head.get(8..12) == Some(b"WEBP") {
        return "WebP signature".into();
    }
    if let Some((_, name)) = known.iter().find(|(sig, _)| head.starts_with(sig)) {
        return format!("{name} signature");
    }
    let hex: Vec<String> = head.iter().take(4).map(|b| format!("{b:02x}")).collect();
    format!("it starts with {} instead of NMAT", hex.join(" "))
}
