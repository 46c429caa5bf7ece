//! Statuses and messages: what every fallible call returns (`nmat_status`), the one message
//! table, the per-thread detail of the last failure (`nmat_last_error`) and `guard`, the status
//! form of the panic boundary that every exported function with a status runs inside.

use crate::boundary::{OnPanic, boundary};
use nmat_core::Error;
use std::cell::{Cell, RefCell};

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
    /// Another call was using the tile cache: a call that changes a cache
    /// (`nmat_cache_begin_frame`, `_mark`, `_mark_texel`, `_mark_tiles`, `_decode_missing`,
    /// `_end_frame`) overlapped with another call on the same cache, from another thread. This
    /// call did nothing; the caller must order its calls (see `nmat_cache_create`).
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

/// A panic inside `guard` (a bug in nmat): `NMAT_INTERNAL_ERROR`, with a message.
impl OnPanic for nmat_status {
    fn on_panic() -> nmat_status {
        set_last_error("internal error: a panic was caught at the C boundary".into());
        NMAT_INTERNAL_ERROR
    }
}

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
    /// Whether the current call has set `LAST_ERROR` (reset by `guard`).
    static SET_THIS_CALL: Cell<bool> = const { Cell::new(false) };
}

/// Records the detail of this call's failure, for `nmat_last_error`.
pub(crate) fn set_last_error(text: String) {
    LAST_ERROR.with(|e| *e.borrow_mut() = text);
    SET_THIS_CALL.with(|s| s.set(true));
}

/// The status of a core error.
pub(crate) fn status_of(e: &Error) -> nmat_status {
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

/// A core error as a status, its message recorded.
pub(crate) fn fail(e: Error) -> nmat_status {
    set_last_error(e.to_string());
    status_of(&e)
}

/// An argument out of range: `NMAT_BAD_ARGUMENT`, naming it.
pub(crate) fn bad(what: &str) -> nmat_status {
    set_last_error(format!("bad argument: {what}"));
    NMAT_BAD_ARGUMENT
}

/// Runs the body of an exported function inside the panic boundary ([`boundary`]; a panic is
/// `NMAT_INTERNAL_ERROR`). A failure that set no detail of its own gets its status's message, so
/// `nmat_last_error` never describes an earlier call.
pub(crate) fn guard(f: impl FnOnce() -> Result<(), nmat_status>) -> nmat_status {
    boundary(|| {
        SET_THIS_CALL.with(|s| s.set(false));
        match f() {
            Ok(()) => NMAT_OK,
            Err(status) => {
                if !SET_THIS_CALL.with(Cell::get) {
                    set_last_error(status.message().into());
                }
                status
            }
        }
    })
}

/// Writes a readable description of `status` (an `nmat_status` value) into `buf`
/// (NUL-terminated, truncated to `len`) and returns the length the full message needs including
/// the NUL. `buf` may be NULL with `len` 0 to ask for the length.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_status_message(status: i32, buf: *mut u8, len: usize) -> usize {
    boundary(|| {
        let text =
            nmat_status::from_i32(status).map_or("unknown nmat_status", nmat_status::message);
        copy_message(text, buf, len)
    })
}

/// The detail of the last failure on this thread (which field of the file, which argument), like
/// `nmat_status_message`. Empty if nothing failed yet.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_last_error(buf: *mut u8, len: usize) -> usize {
    boundary(|| LAST_ERROR.with(|e| copy_message(&e.borrow(), buf, len)))
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
