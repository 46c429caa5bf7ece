//! The material handle (`nmat_material`): opening, freeing and describing a material.

use crate::boundary::boundary;
use crate::pointers::{Castable, OwnershipArc, free_arc, to_arc_ptr, try_ref};
use crate::pointers::{arg_mut, slice};
use crate::status::nmat_status::*;
use crate::status::{bad, fail, guard, nmat_status};
use nmat_core::{Container, Decoder, Material};

/// An opened material. Opaque; create with `nmat_material_open*`, destroy with
/// `nmat_material_free`. (Not `repr(C)`: C sees only an incomplete type.)
pub struct nmat_material {
    _private: [u8; 0],
}

/// What `nmat_material_info` reports.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct nmat_info {
    pub width: u32,
    pub height: u32,
    pub mip_count: u32,
    pub channel_count: u32,
    /// 0 wrap, 1 clamp.
    pub address_mode: u32,
    /// Minor version of the file's format (2: entropy-coded latents). Files of format 1.x (the
    /// legacy layout) and 2.x both open; this struct does not report which major.
    pub format_minor: u32,
    /// Bytes of the file as opened (a packed file is held unpacked: `nmat_material_memory`).
    pub file_size: u64,
    /// Bits per pixel per channel of the file as opened: file bits / (width · height · channels
    /// that carry information; a constant channel is not counted).
    pub bppc: f64,
}

/// What `nmat_material_channel` reports.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct nmat_channel_info {
    /// NUL-terminated UTF-8, at most 16 bytes before the NUL.
    pub name: [u8; 17],
    /// 0 unknown, 1 albedo, 2 normal, 3 roughness, 4 gloss, 5 height, 6 ambient occlusion,
    /// 7 metallic, 8 emissive, 9 opacity, 10 specular (others may appear: treat as unknown).
    pub semantic: u8,
    /// Component within its map (0 = R/X … 3 = A).
    pub component: u8,
    /// 0 linear, 1 sRGB.
    pub color_space: u8,
    /// Decoded values lie in [range_min, range_max].
    pub range_min: f32,
    pub range_max: f32,
}

impl Castable for nmat_material {
    type Ownership = OwnershipArc;
    type RustType = Handle;
}

/// The bytes of an opened material: a copy the handle owns (`nmat_material_open`) or the
/// caller's (`nmat_material_open_borrowed`).
enum Bytes {
    Copied(Box<[u8]>),
    Borrowed { data: *const u8, len: usize },
}

impl Bytes {
    fn as_slice(&self) -> &[u8] {
        match self {
            Bytes::Copied(b) => b,
            // SAFETY: the contract of `nmat_material_open_borrowed`: the `len` bytes at `data`
            // stay valid and unchanged until the handle's last reference is given back (its
            // `nmat_material_free`, and `nmat_cache_free` of every cache made with it), which
            // drops this value.
            Bytes::Borrowed { data, len } => unsafe { std::slice::from_raw_parts(*data, *len) },
        }
    }
}

// SAFETY: the bytes are only ever read, and the C contract lets a handle (and so its bytes) be
// used from any thread, by any number of threads at once.
unsafe impl Send for Bytes {}
// SAFETY: as for `Send`: shared access is read-only.
unsafe impl Sync for Bytes {}

self_cell::self_cell!(
    /// A parsed material together with the bytes it borrows.
    struct Parsed {
        owner: Bytes,
        #[covariant]
        dependent: Material,
    }
);

/// The one owner behind `nmat_material*`: the bytes, the material parsed from them and the
/// material's MLP prepared for the fastest kernel of this CPU (every decode uses it).
pub(crate) struct Handle {
    parsed: Parsed,
    pub(crate) decoder: Decoder,
    /// Length and format minor of the file as given (a packed file's, before unpacking).
    opened: (usize, u16),
}

impl Handle {
    pub(crate) fn material(&self) -> &Material<'_> {
        self.parsed.borrow_dependent()
    }
}

// A handle is shared between threads by C callers: keep that a compile-time fact.
const _: fn() = || {
    fn shareable<T: Send + Sync>() {}
    shareable::<Handle>();
};

/// The handle behind `m`.
pub(crate) fn handle<'a>(m: *const nmat_material) -> Result<&'a Handle, nmat_status> {
    try_ref(m)
}

/// The material behind `m`.
pub(crate) fn material<'a>(m: *const nmat_material) -> Result<&'a Material<'a>, nmat_status> {
    handle(m).map(Handle::material)
}

fn open(data: *const u8, len: usize, out: *mut *mut nmat_material, copy: bool) -> nmat_status {
    guard(|| {
        let out = arg_mut(out)?;
        *out = std::ptr::null_mut();
        let bytes = slice(data, len)?;
        let minor = bytes.get(6..8).map_or(0, |m| u16::from_le_bytes([m[0], m[1]]));
        let opened = (len, minor);
        // A file whose header or table is broken is not packed: parsing names what is wrong.
        let bytes = if let Some(n) = nmat_core::unpacked_len(bytes).ok().flatten() {
            // Entropy-coded latents: decoded once into memory the handle owns, whatever `copy`.
            let mut v = Vec::new();
            v.try_reserve_exact(n).map_err(|_| NMAT_OUT_OF_MEMORY)?;
            v.resize(n, 0);
            nmat_core::unpack_into(bytes, nmat_core::ParseOptions::default(), &mut v)
                .map_err(fail)?;
            Bytes::Copied(v.into_boxed_slice())
        } else if copy {
            let mut v = Vec::new();
            v.try_reserve_exact(len).map_err(|_| NMAT_OUT_OF_MEMORY)?;
            v.extend_from_slice(bytes);
            Bytes::Copied(v.into_boxed_slice())
        } else {
            Bytes::Borrowed { data, len }
        };
        let parsed = Parsed::try_new(bytes, |b| Container::parse(b.as_slice())).map_err(fail)?;
        let decoder = Decoder::new(parsed.borrow_dependent());
        *out = to_arc_ptr(Handle { parsed, decoder, opened });
        Ok(())
    })
}

/// Parses and validates `len` bytes at `data` and returns a handle in `*out` (NULL on error).
/// The bytes are **copied**: the caller may free them as soon as this returns. A packed file
/// (format 2.2, entropy-coded latents) is unpacked into the handle's memory.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_open(
    data: *const u8,
    len: usize,
    out: *mut *mut nmat_material,
) -> nmat_status {
    open(data, len, out, true)
}

/// Like `nmat_material_open` without the copy: the `len` bytes at `data` must stay valid and
/// unchanged until `nmat_material_free` and, if tile caches were made with the handle, until the
/// last of them is freed (e.g. a memory-mapped file). Saves one copy of the file — of a
/// fixed-rate file: a packed one (format 2.2) is unpacked into memory the handle owns, and the
/// caller's bytes are not used after this returns.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_open_borrowed(
    data: *const u8,
    len: usize,
    out: *mut *mut nmat_material,
) -> nmat_status {
    open(data, len, out, false)
}

/// Destroys a handle. NULL is accepted and ignored. Using the handle afterwards is undefined. A
/// tile cache made with it holds its own reference and stays valid: the material is destroyed
/// with the last of them.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_free(m: *mut nmat_material) {
    boundary(|| free_arc(m));
}

/// Size, mips, channels, addressing and rate of a material.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_info(m: *const nmat_material, out: *mut nmat_info) -> nmat_status {
    guard(|| {
        let (h, out) = (handle(m)?, arg_mut(out)?);
        let m = h.material();
        let (file_size, format_minor) = h.opened;
        *out = nmat_info {
            width: m.width(),
            height: m.height(),
            mip_count: m.mip_count(),
            channel_count: m.channel_count() as u32,
            address_mode: m.address_mode() as u32,
            format_minor: u32::from(format_minor),
            file_size: file_size as u64,
            bppc: m.bppc_of(file_size),
        };
        Ok(())
    })
}

/// Bytes the material holds in memory: its fixed-rate form, which a packed file (format 2.2)
/// is unpacked to when opened; for other files, `file_size` of `nmat_material_info`.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_memory(m: *const nmat_material, out: *mut u64) -> nmat_status {
    guard(|| {
        let (m, out) = (material(m)?, arg_mut(out)?);
        *out = m.file_len() as u64;
        Ok(())
    })
}

/// Description of channel `index` (< channel_count).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_channel(
    m: *const nmat_material,
    index: u32,
    out: *mut nmat_channel_info,
) -> nmat_status {
    guard(|| {
        let (m, out) = (material(m)?, arg_mut(out)?);
        let c = m.channels().get(index as usize).ok_or_else(|| bad("channel index"))?;
        let mut name = [0u8; 17];
        name.iter_mut().zip(c.name.as_bytes()).for_each(|(d, s)| *d = *s);
        *out = nmat_channel_info {
            name,
            semantic: c.semantic.0,
            component: c.component,
            color_space: c.color_space as u8,
            range_min: c.range_min,
            range_max: c.range_max,
        };
        Ok(())
    })
}

/// Width and height of `mip` (< mip_count).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_mip_size(
    m: *const nmat_material,
    mip: u32,
    width: *mut u32,
    height: *mut u32,
) -> nmat_status {
    guard(|| {
        let m = material(m)?;
        let (w, h) = (arg_mut(width)?, arg_mut(height)?);
        if mip >= m.mip_count() {
            return Err(bad("mip beyond the chain"));
        }
        (*w, *h) = m.mip_size(mip);
        Ok(())
    })
}

/// The work of decoding every texel of `mip` (< mip_count) once: `*texels` of the mip and
/// `*macs`, the network's multiply-adds over them (all channels). A small file may declare a
/// 16384² chain: check before decoding it whole. The time is `macs` over the rate `nmat bench`
/// measures on the target machine.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_cost(
    m: *const nmat_material,
    mip: u32,
    texels: *mut u64,
    macs: *mut u64,
) -> nmat_status {
    guard(|| {
        let m = material(m)?;
        let (texels, macs) = (arg_mut(texels)?, arg_mut(macs)?);
        if mip >= m.mip_count() {
            return Err(bad("mip beyond the chain"));
        }
        let cost = m.decode_cost(mip);
        (*texels, *macs) = (cost.texels, cost.macs);
        Ok(())
    })
}
