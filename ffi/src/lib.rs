//! The C API of nmat: `bindings-c/include/nmat.h` (generated from this file by cbindgen) and
//! the library `libnmat.a` / `libnmat.so` built from this crate. The guide for C, C++, Android
//! and iOS users (building, linking, pkg-config, the API in brief, the rules every function
//! follows) is `docs/INTEGRATION.md` of the repository, embedded here as [`guide`].
//!
//! ```c
//! #include "nmat.h"
//! nmat_material *m = NULL;
//! if (nmat_material_open(bytes, len, &m) != NMAT_OK) { /* nmat_last_error says why */ }
//! size_t row, total;                      /* the fast path: whole regions, not texels */
//! nmat_required_size(m, w, h, 0x7, 1, 0, &row, &total);
//! nmat_decode_region_u8(m, mip, 0, 0, w, h, 0x7, buffer, row, total);
//! nmat_material_free(m);
//! ```
//!
//! Boundary rules: every exported function runs inside one panic boundary (`guard`); pointers
//! are checked through one set of helpers (`arg`, `arg_mut`, `slice`, `slice_mut`) that answer
//! `NMAT_NULL_ARGUMENT` for NULL and `NMAT_MISALIGNED_ARGUMENT` for an address that is not a
//! multiple of its type's alignment, before any reference or slice is formed; nothing here
//! unwraps or asserts on caller input. A material handle is immutable after `nmat_material_open*`,
//! so one handle may be used from any number of threads at once; a tile cache detects calls that
//! overlap where they must not (`NMAT_CACHE_BUSY`, see `cache`).

// The C names are the API.
#![allow(non_camel_case_types)]

/// Using nmat from C, C++, Android and iOS (`docs/INTEGRATION.md` of the repository).
#[cfg(doc)]
#[doc = include_str!("../../docs/INTEGRATION.md")]
#[allow(rustdoc::broken_intra_doc_links)]
pub mod guide {}

mod cache;
pub use cache::*;

use nmat_core::{
    ChannelMask, Container, Decoder, Error, Filter, Material, Precision, SampleRequest,
};
use std::cell::{Cell, RefCell};
use std::panic::{AssertUnwindSafe, catch_unwind};

/// Version of this library: major.minor.patch.
pub const NMAT_VERSION_MAJOR: u32 = 0;
pub const NMAT_VERSION_MINOR: u32 = 1;
pub const NMAT_VERSION_PATCH: u32 = 0;
/// `(major << 16) | (minor << 8) | patch`, the value `nmat_version()` returns.
pub const NMAT_VERSION: u32 =
    (NMAT_VERSION_MAJOR << 16) | (NMAT_VERSION_MINOR << 8) | NMAT_VERSION_PATCH;

/// Result of every fallible call. 0 is success; the numbers are stable across versions.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum nmat_status {
    NMAT_OK = 0,
    /// A required pointer argument was NULL.
    NMAT_NULL_ARGUMENT = 1,
    /// An argument is out of range (channel mask, mip, region, mode, filter).
    NMAT_BAD_ARGUMENT = 2,
    /// The output buffer (or row pitch) is smaller than the call needs.
    NMAT_BUFFER_TOO_SMALL = 3,
    /// A size computation would overflow `size_t`.
    NMAT_SIZE_OVERFLOW = 4,
    /// A pointer argument is not aligned for its type: its address is not a multiple of the
    /// type's alignment (4 bytes for `float`, 2 for `nmat_tile_key`, 8 for `size_t` on 64-bit
    /// targets, …). Nothing was read or written.
    NMAT_MISALIGNED_ARGUMENT = 5,
    /// Another call was using the tile cache: a call that changes a cache (`nmat_cache_begin_frame`,
    /// `_mark`, `_mark_texel`, `_mark_tiles`, `_decode_missing`, `_end_frame`) overlapped with
    /// another call on the same cache, from another thread. This call did nothing; the caller must
    /// order its calls (see `nmat_cache_create`).
    NMAT_CACHE_BUSY = 6,
    /// The file contradicts the format (see `nmat_last_error` for the field).
    NMAT_MALFORMED = 10,
    /// The file is shorter than its contents need.
    NMAT_TRUNCATED = 11,
    /// The file uses a version or feature this library does not know.
    NMAT_UNSUPPORTED = 12,
    /// The file exceeds a limit of this library.
    NMAT_LIMIT_EXCEEDED = 13,
    /// The file's checksum does not match: it was corrupted.
    NMAT_CHECKSUM_MISMATCH = 14,
    /// Memory for the handle could not be allocated.
    NMAT_OUT_OF_MEMORY = 20,
    /// An internal error (a bug in nmat) was caught at the boundary.
    NMAT_INTERNAL_ERROR = 99,
}

use nmat_status::*;

impl nmat_status {
    /// Every status, for turning a number back into one.
    const ALL: [nmat_status; 14] = [
        NMAT_OK,
        NMAT_NULL_ARGUMENT,
        NMAT_BAD_ARGUMENT,
        NMAT_BUFFER_TOO_SMALL,
        NMAT_SIZE_OVERFLOW,
        NMAT_MISALIGNED_ARGUMENT,
        NMAT_CACHE_BUSY,
        NMAT_MALFORMED,
        NMAT_TRUNCATED,
        NMAT_UNSUPPORTED,
        NMAT_LIMIT_EXCEEDED,
        NMAT_CHECKSUM_MISMATCH,
        NMAT_OUT_OF_MEMORY,
        NMAT_INTERNAL_ERROR,
    ];

    fn from_i32(v: i32) -> Option<nmat_status> {
        nmat_status::ALL.into_iter().find(|s| *s as i32 == v)
    }

    /// The one message table: `nmat_status_message`, and the detail of a failure that has no
    /// more specific one.
    fn message(self) -> &'static str {
        match self {
            NMAT_OK => "success",
            NMAT_NULL_ARGUMENT => "a required pointer argument is NULL",
            NMAT_BAD_ARGUMENT => "an argument is out of range",
            NMAT_BUFFER_TOO_SMALL => "the output buffer is too small",
            NMAT_SIZE_OVERFLOW => "a size computation overflows",
            NMAT_MISALIGNED_ARGUMENT => {
                "a pointer argument is not aligned for its type (a float buffer must start at a \
                 multiple of 4 bytes, an nmat_tile_key buffer at a multiple of 2)"
            }
            NMAT_CACHE_BUSY => {
                "another thread is using this cache: calls that change a cache must not overlap \
                 with any other call on it"
            }
            NMAT_MALFORMED => "the .nmat data is malformed",
            NMAT_TRUNCATED => "the .nmat data is truncated",
            NMAT_UNSUPPORTED => "the .nmat data uses an unsupported version or feature",
            NMAT_LIMIT_EXCEEDED => "the .nmat data exceeds a limit of this library",
            NMAT_CHECKSUM_MISMATCH => "the .nmat data is corrupted (checksum mismatch)",
            NMAT_OUT_OF_MEMORY => "out of memory",
            NMAT_INTERNAL_ERROR => "internal error in nmat",
        }
    }
}

/// Which decoder computes the values.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum nmat_mode {
    /// Integer-exact (W8A16): bit-identical on every platform and on the GPU runtime.
    NMAT_MODE_INTEGER = 0,
    /// The float reference decoder (the int8 network dequantized, f32 arithmetic).
    NMAT_MODE_FLOAT = 1,
}

/// Texture filter of `nmat_sample`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum nmat_filter {
    NMAT_FILTER_NEAREST = 0,
    NMAT_FILTER_BILINEAR = 1,
    NMAT_FILTER_TRILINEAR = 2,
    /// One decode per sample, the texel drawn with the caller's random numbers.
    NMAT_FILTER_STOCHASTIC = 3,
}

/// A BC (GPU block-compressed) format of `nmat_bc_texture`; the numbers are stable.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum nmat_bc_format {
    /// RGB, 8 bytes per 4×4 block (`DXGI_FORMAT_BC1_UNORM[_SRGB]`); never transparent.
    NMAT_BC1 = 1,
    /// One channel, 8 bytes per block (`BC4_UNORM`).
    NMAT_BC4 = 4,
    /// Two channels, 16 bytes per block (`BC5_UNORM`).
    NMAT_BC5 = 5,
    /// RGB in BC7, alpha 255, 16 bytes per block (`BC7_UNORM[_SRGB]`).
    NMAT_BC7_RGB = 7,
    /// RGBA in BC7, 16 bytes per block.
    NMAT_BC7_RGBA = 8,
}

impl nmat_bc_format {
    const ALL: [nmat_bc_format; 5] = [
        nmat_bc_format::NMAT_BC1,
        nmat_bc_format::NMAT_BC4,
        nmat_bc_format::NMAT_BC5,
        nmat_bc_format::NMAT_BC7_RGB,
        nmat_bc_format::NMAT_BC7_RGBA,
    ];

    fn core(self) -> nmat_core::bc::BcFormat {
        use nmat_core::bc::BcFormat;
        match self {
            nmat_bc_format::NMAT_BC1 => BcFormat::Bc1,
            nmat_bc_format::NMAT_BC4 => BcFormat::Bc4,
            nmat_bc_format::NMAT_BC5 => BcFormat::Bc5,
            nmat_bc_format::NMAT_BC7_RGB => BcFormat::Bc7Rgb,
            nmat_bc_format::NMAT_BC7_RGBA => BcFormat::Bc7Rgba,
        }
    }

    fn from_u32(v: u32) -> Option<nmat_bc_format> {
        nmat_bc_format::ALL.into_iter().find(|f| *f as u32 == v)
    }

    fn of(f: nmat_core::bc::BcFormat) -> nmat_bc_format {
        nmat_bc_format::ALL.into_iter().find(|c| c.core() == f).unwrap_or(nmat_bc_format::NMAT_BC1)
    }
}

/// One BC texture made from a material: its format (an `nmat_bc_format`), the material channels
/// of its R, G, B, A components (the first 1, 2, 3 or 4 are used, by format; repeats allowed),
/// and whether to sample it as sRGB (1; BC1 and BC7 only).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct nmat_bc_texture {
    pub format: u32,
    pub channels: [u8; 4],
    pub srgb: u32,
}

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
    /// Minor version of the file's format (major is always 1).
    pub format_minor: u32,
    /// Bytes of the file.
    pub file_size: u64,
    /// Bits per pixel per channel: file bits / (width · height · channels).
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

/// Maps an opaque C type to the one Rust type behind its pointers, which C receives as a
/// `Box<RustType>` turned into a raw pointer (the pattern of rustls-ffi's `Castable`): every
/// conversion between the two goes through [`to_boxed_ptr`], [`try_ref`] and [`free_box`].
trait Castable {
    type RustType;
}

impl Castable for nmat_material {
    type RustType = Handle;
}

/// Gives `value` to C as a `*mut C`, to be freed once by [`free_box`].
fn to_boxed_ptr<C: Castable>(value: C::RustType) -> *mut C {
    Box::into_raw(Box::new(value)).cast::<C>()
}

/// The value behind a pointer from [`to_boxed_ptr`]; NULL is `NMAT_NULL_ARGUMENT`. (No `try_mut`:
/// a handle that calls change, the tile cache, keeps its state in an `UnsafeCell` reached through
/// this shared reference and guarded by an atomic, so two threads never hold `&mut` to it.)
fn try_ref<'a, C: Castable>(p: *const C) -> Result<&'a C::RustType, nmat_status> {
    arg(p.cast::<C::RustType>())
}

/// Drops the value behind a pointer from [`to_boxed_ptr`]; NULL is ignored.
fn free_box<C: Castable>(p: *mut C) {
    if !p.is_null() {
        // SAFETY: a non-NULL `p` came from `to_boxed_ptr::<C>` and is freed once (the caller's
        // contract of every `*_free` function).
        drop(unsafe { Box::from_raw(p.cast::<C::RustType>()) });
    }
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
            // stay valid and unchanged until `nmat_material_free`, which drops this value.
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
struct Handle {
    parsed: Parsed,
    decoder: Decoder,
}

impl Handle {
    fn material(&self) -> &Material<'_> {
        self.parsed.borrow_dependent()
    }
}

// A handle is shared between threads by C callers: keep that a compile-time fact.
const _: fn() = || {
    fn shareable<T: Send + Sync>() {}
    shareable::<Handle>();
};

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
    /// Whether the current call has set `LAST_ERROR` (reset by `guard`).
    static SET_THIS_CALL: Cell<bool> = const { Cell::new(false) };
}

fn set_last_error(text: String) {
    LAST_ERROR.with(|e| *e.borrow_mut() = text);
    SET_THIS_CALL.with(|s| s.set(true));
}

fn status_of(e: &Error) -> nmat_status {
    match e {
        Error::Malformed { .. } => NMAT_MALFORMED,
        Error::Truncated { .. } => NMAT_TRUNCATED,
        Error::Unsupported { .. } => NMAT_UNSUPPORTED,
        Error::LimitExceeded { .. } => NMAT_LIMIT_EXCEEDED,
        Error::ChecksumMismatch { .. } => NMAT_CHECKSUM_MISMATCH,
        Error::OutOfMemory { .. } => NMAT_OUT_OF_MEMORY,
        Error::BadArgument {
            argument: nmat_core::Argument::Output | nmat_core::Argument::RowPitch,
            ..
        } => NMAT_BUFFER_TOO_SMALL,
        _ => NMAT_BAD_ARGUMENT,
    }
}

fn fail(e: Error) -> nmat_status {
    set_last_error(e.to_string());
    status_of(&e)
}

/// The one panic boundary: runs `f`, turns a panic into `NMAT_INTERNAL_ERROR`.
/// A failure that set no detail of its own gets its status's message, so `nmat_last_error` never
/// describes an earlier call.
fn guard(f: impl FnOnce() -> Result<(), nmat_status>) -> nmat_status {
    SET_THIS_CALL.with(|s| s.set(false));
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => NMAT_OK,
        Ok(Err(status)) => {
            if !SET_THIS_CALL.with(Cell::get) {
                set_last_error(status.message().into());
            }
            status
        }
        Err(_) => {
            set_last_error("internal error: a panic was caught at the C boundary".into());
            NMAT_INTERNAL_ERROR
        }
    }
}

/// The one null and alignment check of a pointer from C, before any reference or slice is made
/// from it (both must be aligned, even for zero elements). `what` names the pointer in the
/// message.
fn check_ptr<T>(p: *const T, what: &str) -> Result<(), nmat_status> {
    if p.is_null() {
        set_last_error(format!("a required {what} is NULL"));
        return Err(NMAT_NULL_ARGUMENT);
    }
    if !p.is_aligned() {
        set_last_error(format!(
            "the {what} {p:p} is not aligned for its type: {} values must start at a multiple \
             of {} bytes",
            c_type_name::<T>(),
            align_of::<T>()
        ));
        return Err(NMAT_MISALIGNED_ARGUMENT);
    }
    Ok(())
}

/// The C name of `T`, for messages: `float`, `size_t`, `nmat_tile_key`, …
fn c_type_name<T>() -> &'static str {
    match std::any::type_name::<T>() {
        "f32" => "float",
        "f64" => "double",
        "usize" => "size_t",
        "u8" => "uint8_t",
        "u16" => "uint16_t",
        "u32" => "uint32_t",
        "u64" => "uint64_t",
        "i32" => "int32_t",
        "i64" => "int64_t",
        name if name.starts_with('*') => "pointer",
        // Our own types: the C name is the last path segment (`nmat::cache::nmat_tile_key`).
        name => name.rsplit("::").next().unwrap_or(name),
    }
}

/// The one null and alignment check for inputs.
fn arg<'a, T>(p: *const T) -> Result<&'a T, nmat_status> {
    check_ptr(p, "pointer argument")?;
    // SAFETY: `p` is non-NULL and aligned (checked above), and the C contract of every function
    // taking `p` is that it points to a valid, live `T` for the duration of the call.
    Ok(unsafe { &*p })
}

/// The one null and alignment check for outputs.
fn arg_mut<'a, T>(p: *mut T) -> Result<&'a mut T, nmat_status> {
    check_ptr(p.cast_const(), "output pointer")?;
    // SAFETY: as for `arg`, and the caller does not alias the pointee during the call.
    Ok(unsafe { &mut *p })
}

/// A length no object can have (more than `isize::MAX` bytes): an error, not a slice.
fn check_len<T>(len: usize) -> Result<(), nmat_status> {
    if len.checked_mul(size_of::<T>()).is_none_or(|b| b > isize::MAX as usize) {
        set_last_error(format!("a length of {len} elements is larger than any buffer can be"));
        return Err(NMAT_SIZE_OVERFLOW);
    }
    Ok(())
}

/// The one (pointer, length) → slice conversion (NULL, misaligned and impossible lengths are
/// statuses).
fn slice<'a, T>(p: *const T, len: usize) -> Result<&'a [T], nmat_status> {
    check_ptr(p, "pointer argument")?;
    check_len::<T>(len)?;
    // SAFETY: `p` is non-NULL and aligned and `len` elements fit in `isize::MAX` bytes (checked
    // above); the caller guarantees `len` readable elements at `p` (the documented contract).
    Ok(unsafe { std::slice::from_raw_parts(p, len) })
}

/// [`slice`] for outputs.
fn slice_mut<'a, T>(p: *mut T, len: usize) -> Result<&'a mut [T], nmat_status> {
    check_ptr(p.cast_const(), "output pointer")?;
    check_len::<T>(len)?;
    // SAFETY: as for `slice`, and the caller guarantees `len` writable elements at `p`, not
    // aliased during the call.
    Ok(unsafe { std::slice::from_raw_parts_mut(p, len) })
}

fn handle<'a>(m: *const nmat_material) -> Result<&'a Handle, nmat_status> {
    try_ref(m)
}

fn material<'a>(m: *const nmat_material) -> Result<&'a Material<'a>, nmat_status> {
    handle(m).map(Handle::material)
}

fn bad(what: &str) -> nmat_status {
    set_last_error(format!("bad argument: {what}"));
    NMAT_BAD_ARGUMENT
}

/// `(major << 16) | (minor << 8) | patch` of the library, to compare with `NMAT_VERSION` from
/// the header the caller compiled against.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_version() -> u32 {
    NMAT_VERSION
}

fn open(data: *const u8, len: usize, out: *mut *mut nmat_material, copy: bool) -> nmat_status {
    guard(|| {
        let out = arg_mut(out)?;
        *out = std::ptr::null_mut();
        let bytes = slice(data, len)?;
        let bytes = if copy {
            let mut v = Vec::new();
            v.try_reserve_exact(len).map_err(|_| NMAT_OUT_OF_MEMORY)?;
            v.extend_from_slice(bytes);
            Bytes::Copied(v.into_boxed_slice())
        } else {
            Bytes::Borrowed { data, len }
        };
        let parsed = Parsed::try_new(bytes, |b| Container::parse(b.as_slice())).map_err(fail)?;
        let decoder = Decoder::new(parsed.borrow_dependent());
        *out = to_boxed_ptr(Handle { parsed, decoder });
        Ok(())
    })
}

/// Parses and validates `len` bytes at `data` and returns a handle in `*out` (NULL on error).
/// The bytes are **copied**: the caller may free them as soon as this returns.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_open(
    data: *const u8,
    len: usize,
    out: *mut *mut nmat_material,
) -> nmat_status {
    open(data, len, out, true)
}

/// Like `nmat_material_open` without the copy: the `len` bytes at `data` must stay valid and
/// unchanged until `nmat_material_free` (e.g. a memory-mapped file). Saves one copy of the file.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_open_borrowed(
    data: *const u8,
    len: usize,
    out: *mut *mut nmat_material,
) -> nmat_status {
    open(data, len, out, false)
}

/// Destroys a handle. NULL is accepted and ignored. Using the handle afterwards is undefined.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_free(m: *mut nmat_material) {
    let _ = guard(|| {
        free_box(m);
        Ok(())
    });
}

/// Size, mips, channels, addressing and rate of a material.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_material_info(m: *const nmat_material, out: *mut nmat_info) -> nmat_status {
    guard(|| {
        let (m, out) = (material(m)?, arg_mut(out)?);
        *out = nmat_info {
            width: m.width(),
            height: m.height(),
            mip_count: m.mip_count(),
            channel_count: m.channel_count() as u32,
            address_mode: m.address_mode() as u32,
            format_minor: u32::from(m.version_minor()),
            file_size: m.file_len() as u64,
            bppc: m.bppc(),
        };
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

fn mask(m: &Material<'_>, channel_mask: u32) -> Result<(ChannelMask, usize), nmat_status> {
    let mask = u16::try_from(channel_mask).map_err(|_| bad("channel mask beyond 16 channels"))?;
    let n = m.required_len(ChannelMask(mask)).map_err(fail)?;
    Ok((ChannelMask(mask), n))
}

/// Decodes texel (x, y) of `mip` for the channels in `channel_mask` (bit c = channel c;
/// 0xFFFF = all) with decoder `mode` (an `nmat_mode`) into `out` (values in each channel's range, packed in channel order).
/// Coordinates outside the mip wrap or clamp by the material's address mode; a mip beyond the
/// chain is `NMAT_BAD_ARGUMENT`.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_texel(
    m: *const nmat_material,
    x: i64,
    y: i64,
    mip: u32,
    channel_mask: u32,
    mode: u32,
    out: *mut f32,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let out = slice_mut(out, out_len)?;
        let (mask, n) = mask(m, channel_mask)?;
        if mip >= m.mip_count() {
            return Err(bad("mip beyond the chain"));
        }
        match decode_mode(mode)? {
            nmat_mode::NMAT_MODE_FLOAT => {
                decoder.decode_texel(m, x, y, mip, mask, out).map(|_| ()).map_err(fail)
            }
            nmat_mode::NMAT_MODE_INTEGER => {
                let mut codes = [0u8; 16];
                decoder.decode_texel_u8(m, x, y, mip, mask, &mut codes).map_err(fail)?;
                let channels = selected(m, mask);
                if out.len() < n {
                    return Err(NMAT_BUFFER_TOO_SMALL);
                }
                for ((o, c), ch) in out.iter_mut().zip(codes).zip(channels) {
                    let u = f32::from(c) / 255.0;
                    *o = ch.range_min * (1.0 - u) + ch.range_max * u;
                }
                Ok(())
            }
        }
    })
}

/// A C enum arrives as an integer that may hold anything: converted here, never transmuted.
fn decode_mode(mode: u32) -> Result<nmat_mode, nmat_status> {
    match mode {
        0 => Ok(nmat_mode::NMAT_MODE_INTEGER),
        1 => Ok(nmat_mode::NMAT_MODE_FLOAT),
        _ => Err(bad("mode is not an nmat_mode")),
    }
}

fn selected<'m>(
    m: &'m Material<'_>,
    mask: ChannelMask,
) -> impl Iterator<Item = &'m nmat_core::Channel<'m>> {
    let bits = mask.resolve(m.channel_count()).unwrap_or(0);
    m.channels().iter().enumerate().filter(move |(i, _)| bits & (1 << i) != 0).map(|(_, c)| c)
}

/// Integer-exact decode of one texel to 8-bit codes (0 = range_min, 255 = range_max).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_texel_u8(
    m: *const nmat_material,
    x: i64,
    y: i64,
    mip: u32,
    channel_mask: u32,
    out: *mut u8,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let out = slice_mut(out, out_len)?;
        let (mask, _) = mask(m, channel_mask)?;
        if mip >= m.mip_count() {
            return Err(bad("mip beyond the chain"));
        }
        decoder.decode_texel_u8(m, x, y, mip, mask, out).map(|_| ()).map_err(fail)
    })
}

/// Filtered sample at normalized (u, v) and fractional `lod` with `filter` (an `nmat_filter`)
/// and decoder `mode` (an `nmat_mode`). `random` points to 3 uniform
/// numbers in [0, 1) for `NMAT_FILTER_STOCHASTIC` (may be NULL for the other filters).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_sample(
    m: *const nmat_material,
    u: f32,
    v: f32,
    lod: f32,
    filter: u32,
    mode: u32,
    random: *const f32,
    channel_mask: u32,
    out: *mut f32,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let out = slice_mut(out, out_len)?;
        let (channels, _) = mask(m, channel_mask)?;
        let precision = match decode_mode(mode)? {
            nmat_mode::NMAT_MODE_INTEGER => Precision::Integer,
            nmat_mode::NMAT_MODE_FLOAT => Precision::Float,
        };
        let req = SampleRequest { precision, channels, ..request(u, v, lod, filter, random)? };
        decoder.sample(m, &req, out).map(|_| ()).map_err(fail)
    })
}

/// The lookup of `nmat_sample` and `nmat_cache_mark`/`_resolve` (integer precision, every
/// channel; callers set the two): the filter checked, `random` read (NULL only when the filter
/// does not use it).
fn request(
    u: f32,
    v: f32,
    lod: f32,
    filter: u32,
    random: *const f32,
) -> Result<SampleRequest, nmat_status> {
    let filter = match filter {
        0 => Filter::Nearest,
        1 => Filter::Bilinear,
        2 => Filter::Trilinear,
        3 => Filter::Stochastic,
        _ => return Err(bad("filter is not an nmat_filter")),
    };
    let random = if random.is_null() {
        if filter == Filter::Stochastic {
            return Err(check_ptr(random, "pointer argument").err().unwrap_or(NMAT_NULL_ARGUMENT));
        }
        [0.0; 3]
    } else {
        let r = slice(random, 3)?;
        [r[0], r[1], r[2]]
    };
    Ok(SampleRequest {
        u,
        v,
        lod,
        filter,
        precision: Precision::Integer,
        random,
        channels: ChannelMask::ALL,
    })
}

/// The buffer a region decode needs: `*row_bytes` = width · channels · bytes_per_value (the
/// smallest valid row pitch) and `*total_bytes` = row_pitch · (height − 1) + row_bytes for the
/// given `row_pitch` (0 = tightly packed). Reports `NMAT_SIZE_OVERFLOW` instead of wrapping.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_required_size(
    m: *const nmat_material,
    width: u32,
    height: u32,
    channel_mask: u32,
    bytes_per_value: usize,
    row_pitch: usize,
    row_bytes: *mut usize,
    total_bytes: *mut usize,
) -> nmat_status {
    guard(|| {
        let m = material(m)?;
        let (row_out, total_out) = (arg_mut(row_bytes)?, arg_mut(total_bytes)?);
        let (_, n) = mask(m, channel_mask)?;
        let (row, total) = region_size(width, height, n, bytes_per_value, row_pitch)?;
        (*row_out, *total_out) = (row, total);
        Ok(())
    })
}

fn region_size(
    width: u32,
    height: u32,
    channels: usize,
    bytes: usize,
    pitch: usize,
) -> Result<(usize, usize), nmat_status> {
    let overflow = || {
        set_last_error("the region's size overflows size_t".into());
        NMAT_SIZE_OVERFLOW
    };
    let row = (width as usize)
        .checked_mul(channels)
        .and_then(|v| v.checked_mul(bytes))
        .ok_or_else(overflow)?;
    let pitch = if pitch == 0 { row } else { pitch };
    if pitch < row {
        set_last_error(format!("row pitch {pitch} is below the row size {row}"));
        return Err(NMAT_BUFFER_TOO_SMALL);
    }
    let total = if height == 0 {
        0
    } else {
        pitch
            .checked_mul(height as usize - 1)
            .and_then(|v| v.checked_add(row))
            .ok_or_else(overflow)?
    };
    Ok((row, total))
}

/// Checks a region against the mip and the buffer; returns (mask, channels, pitch).
fn region_checks(
    m: &Material<'_>,
    mip: u32,
    rect: (u32, u32, u32, u32),
    channel_mask: u32,
    bytes: usize,
    pitch: usize,
    out_len_bytes: usize,
) -> Result<(ChannelMask, usize, usize), nmat_status> {
    let (x0, y0, w, h) = rect;
    if mip >= m.mip_count() {
        return Err(bad("mip beyond the chain"));
    }
    let (mw, mh) = m.mip_size(mip);
    if x0.checked_add(w).is_none_or(|e| e > mw) || y0.checked_add(h).is_none_or(|e| e > mh) {
        return Err(bad("region outside the mip"));
    }
    let (mask, n) = mask(m, channel_mask)?;
    let (row, total) = region_size(w, h, n, bytes, pitch)?;
    if out_len_bytes < total {
        set_last_error(format!("the region needs {total} bytes, the buffer has {out_len_bytes}"));
        return Err(NMAT_BUFFER_TOO_SMALL);
    }
    Ok((mask, n, if pitch == 0 { row } else { pitch }))
}

/// Integer-exact decode of the rectangle (x0, y0, width, height) of `mip` into `out`: rows of
/// `width · channels` codes, `row_pitch` bytes apart (0 = packed), `out_len` bytes in all.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_region_u8(
    m: *const nmat_material,
    mip: u32,
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
    channel_mask: u32,
    out: *mut u8,
    row_pitch: usize,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (m, decoder) = (h.material(), &h.decoder);
        let out = slice_mut(out, out_len)?;
        let (mask, _, pitch) =
            region_checks(m, mip, (x0, y0, width, height), channel_mask, 1, row_pitch, out_len)?;
        decoder
            .decode_region_u8(m, mip, (x0, y0, width, height), mask, out, pitch)
            .map_err(fail)?;
        Ok(())
    })
}

/// Float decode of a rectangle (values in channel ranges): like `nmat_decode_region_u8` with
/// `float` values; `row_pitch` and `out_len` count **bytes**.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_decode_region_f32(
    m: *const nmat_material,
    mip: u32,
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
    channel_mask: u32,
    mode: u32,
    out: *mut f32,
    row_pitch: usize,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let (mm, decoder) = (h.material(), &h.decoder);
        if !row_pitch.is_multiple_of(4) {
            return Err(bad("row pitch of a float region must be a multiple of 4 bytes"));
        }
        let mode = decode_mode(mode)?;
        let out = slice_mut(out, out_len / 4)?;
        let (mask, n, pitch) =
            region_checks(mm, mip, (x0, y0, width, height), channel_mask, 4, row_pitch, out_len)?;
        let ranges: Vec<(f32, f32)> =
            selected(mm, mask).map(|c| (c.range_min, c.range_max)).collect();
        let row_len = width as usize * n;
        let mut codes = vec![0u8; if mode == nmat_mode::NMAT_MODE_INTEGER { row_len } else { 0 }];
        for y in 0..height as usize {
            let start = y * pitch / 4;
            let row = out.get_mut(start..start + row_len).ok_or(NMAT_BUFFER_TOO_SMALL)?;
            let (x, ty) = (i64::from(x0), i64::from(y0) + y as i64);
            let w = width as usize;
            match mode {
                nmat_mode::NMAT_MODE_FLOAT => {
                    decoder.decode_span_f32(mm, x, ty, mip, w, mask, row).map_err(fail)?;
                }
                nmat_mode::NMAT_MODE_INTEGER => {
                    decoder.decode_span_u8(mm, x, ty, mip, w, mask, &mut codes).map_err(fail)?;
                    for (i, (o, &c)) in row.iter_mut().zip(&codes).enumerate() {
                        let (lo, hi) = ranges.get(i % n).copied().unwrap_or((0.0, 1.0));
                        let u = f32::from(c) / 255.0;
                        *o = lo * (1.0 - u) + hi * u;
                    }
                }
            }
        }
        Ok(())
    })
}

/// Bytes per 4×4 block of `format` (an `nmat_bc_format`): 8 or 16; 0 for an unknown format.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_bc_block_bytes(format: u32) -> usize {
    nmat_bc_format::from_u32(format).map_or(0, |f| f.core().block_bytes())
}

/// The BC textures for the material's maps: with `format` 0, chosen from each map's meaning
/// (albedo → BC1 sRGB, normal → BC5 of X and Y, one channel → BC4, two → BC5, a fourth component
/// → its own BC4); with an `nmat_bc_format`, every map in that format (BC7: RGBA for maps of four
/// channels). Sets `*count` (at most 16) and writes that many textures to `out`; with `out` NULL
/// and `capacity` 0 it only sets the count. `NMAT_BUFFER_TOO_SMALL` (with `*count` set, nothing
/// written) when `capacity` is below the count.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_bc_layout(
    m: *const nmat_material,
    format: u32,
    out: *mut nmat_bc_texture,
    capacity: usize,
    count: *mut usize,
) -> nmat_status {
    guard(|| {
        let m = material(m)?;
        let count = arg_mut(count)?;
        let chosen = match format {
            0 => None,
            f => Some(nmat_bc_format::from_u32(f).ok_or_else(|| bad("unknown BC format"))?),
        };
        let layout = nmat_core::bc::layout_with(m, |_| chosen.map(nmat_bc_format::core));
        *count = layout.len();
        if out.is_null() && capacity == 0 {
            return Ok(());
        }
        if capacity < layout.len() {
            set_last_error(format!(
                "the layout has {} textures, the buffer holds {capacity}",
                layout.len()
            ));
            return Err(NMAT_BUFFER_TOO_SMALL);
        }
        if layout.is_empty() {
            return Ok(());
        }
        let out = slice_mut(out, capacity)?;
        for (o, t) in out.iter_mut().zip(&layout) {
            *o = nmat_bc_texture {
                format: nmat_bc_format::of(t.format) as u32,
                channels: t.channels,
                srgb: u32::from(t.srgb),
            };
        }
        Ok(())
    })
}

/// Decodes the blocks (block_x, block_y, blocks_wide, blocks_high) of `mip` — in 4×4 blocks; a
/// mip of w × h texels has ⌈w/4⌉ × ⌈h/4⌉ — with the integer decoder and encodes them as BC
/// blocks of `texture` into `out`: block row r at `out + r · row_pitch` (0 = packed), `out_len`
/// bytes in all. Pixels past the mip's edge do not influence the blocks. The bytes depend only on
/// the material and the arguments (not on the CPU, the kernel or how a mip is split into
/// regions, e.g. across threads). Nothing is written on error.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_transcode_region(
    m: *const nmat_material,
    texture: *const nmat_bc_texture,
    mip: u32,
    block_x: u32,
    block_y: u32,
    blocks_wide: u32,
    blocks_high: u32,
    out: *mut u8,
    row_pitch: usize,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let h = handle(m)?;
        let t = arg(texture)?;
        let format = nmat_bc_format::from_u32(t.format).ok_or_else(|| bad("unknown BC format"))?;
        let texture = nmat_core::bc::BcTexture {
            format: format.core(),
            channels: t.channels,
            srgb: t.srgb != 0,
        };
        let out = slice_mut(out, out_len)?;
        let row =
            (blocks_wide as usize).checked_mul(format.core().block_bytes()).ok_or_else(|| {
                set_last_error("the region's size overflows size_t".into());
                NMAT_SIZE_OVERFLOW
            })?;
        let pitch = if row_pitch == 0 { row } else { row_pitch };
        let region = nmat_core::BlockRegion {
            x: block_x,
            y: block_y,
            width: blocks_wide,
            height: blocks_high,
        };
        h.decoder.transcode_blocks(h.material(), &texture, mip, region, out, pitch).map_err(fail)
    })
}

/// Writes a readable description of `status` (an `nmat_status` value) into `buf` (NUL-terminated, truncated to `len`)
/// and returns the length the full message needs including the NUL. `buf` may be NULL with
/// `len` 0 to ask for the length.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_status_message(status: i32, buf: *mut u8, len: usize) -> usize {
    let text = nmat_status::from_i32(status).map_or("unknown nmat_status", nmat_status::message);
    copy_message(text, buf, len)
}

/// The detail of the last failure on this thread (which field of the file, which argument), like
/// `nmat_status_message`. Empty if nothing failed yet.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_last_error(buf: *mut u8, len: usize) -> usize {
    LAST_ERROR.with(|e| copy_message(&e.borrow(), buf, len))
}

fn copy_message(text: &str, buf: *mut u8, len: usize) -> usize {
    let needed = text.len() + 1;
    // No `slice_mut` here: a NULL buffer is a valid question, not an error to record.
    if !buf.is_null() && len > 0 {
        // SAFETY: the caller provides `len` writable bytes at a non-NULL `buf`.
        let out = unsafe { std::slice::from_raw_parts_mut(buf, len) };
        if let Some((last, body)) = out.split_last_mut() {
            let n = body.len().min(text.len());
            body[..n].copy_from_slice(&text.as_bytes()[..n]);
            let end = body.get_mut(n).unwrap_or(last);
            *end = 0;
        }
    }
    needed
}
