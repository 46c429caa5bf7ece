//! The C API of nmat: `bindings-c/include/nmat.h` (generated from this crate by cbindgen) and
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
//! Boundary rules: every exported function runs inside one panic boundary (`boundary`; with a
//! status through `status::guard`); pointers are checked through one set of helpers
//! (`pointers`: `arg`, `arg_mut`, `slice`, `slice_mut`) that answer `NMAT_NULL_ARGUMENT` for NULL
//! and `NMAT_MISALIGNED_ARGUMENT` for an address that is not a multiple of its type's alignment,
//! before any reference or slice is formed; nothing here unwraps or asserts on caller input. A
//! material handle is immutable after `nmat_material_open*` and reference-counted, so one handle
//! may be used from any number of threads at once and a tile cache holds its materials itself; a
//! tile cache detects calls that overlap where they must not (`NMAT_CACHE_BUSY`, see `cache`).
//!
//! One module per part of the API: `status` (statuses, messages, the last error), `material`
//! (the handle), `decode`, `sample`, `bc` and `cache` (the tile cache handle), over `pointers`
//! and `boundary`.

// The C names are the API.
#![allow(non_camel_case_types)]
// The C boundary: `no_mangle` exports, raw pointers from C, the handles' ownership. Every unsafe
// block still says why it is sound (clippy's undocumented_unsafe_blocks, denied workspace-wide).
#![allow(unsafe_code)]

/// Using nmat from C, C++, Android and iOS (`docs/INTEGRATION.md` of the repository).
#[cfg(doc)]
#[doc = include_str!("../../docs/INTEGRATION.md")]
#[allow(rustdoc::broken_intra_doc_links)]
pub mod guide {}

mod bc;
mod boundary;
mod cache;
mod decode;
mod material;
mod pointers;
mod sample;
mod status;

pub use bc::*;
pub use cache::*;
pub use decode::*;
pub use material::*;
pub use sample::*;
pub use status::*;

use boundary::boundary;

/// Version of this library: major.minor.patch.
pub const NMAT_VERSION_MAJOR: u32 = 0;
pub const NMAT_VERSION_MINOR: u32 = 1;
pub const NMAT_VERSION_PATCH: u32 = 0;
/// `(major << 16) | (minor << 8) | patch`, the value `nmat_version()` returns.
pub const NMAT_VERSION: u32 =
    (NMAT_VERSION_MAJOR << 16) | (NMAT_VERSION_MINOR << 8) | NMAT_VERSION_PATCH;

/// `(major << 16) | (minor << 8) | patch` of the library, to compare with `NMAT_VERSION` from
/// the header the caller compiled against.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_version() -> u32 {
    boundary(|| NMAT_VERSION)
}
