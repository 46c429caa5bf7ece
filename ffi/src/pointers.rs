//! Pointers from C: the one conversion of each kind, checked before any reference or slice is
//! made (NULL, alignment, impossible lengths), and the ownership of the opaque handles given to C
//! (the pattern of rustls-ffi's `Castable`).

use crate::status::nmat_status::{
    self, NMAT_MISALIGNED_ARGUMENT, NMAT_NULL_ARGUMENT, NMAT_SIZE_OVERFLOW,
};
use crate::status::set_last_error;
use std::sync::Arc;

/// Maps an opaque C type to the one Rust type behind its pointers and says who owns it (the
/// pattern of rustls-ffi's `Castable`): C receives a `Box<RustType>` ([`OwnershipBox`]: one owner,
/// freed once) or an `Arc<RustType>` ([`OwnershipArc`]: C holds one reference, and so may other
/// handles, such as a tile cache holding its materials) turned into a raw pointer. Every
/// conversion between the two goes through the functions below.
pub(crate) trait Castable {
    type Ownership;
    type RustType;
}

/// The C pointer is a `Box` (`to_boxed_ptr` / `free_box`).
pub(crate) struct OwnershipBox;
/// The C pointer is one reference of an `Arc` (`to_arc_ptr` / `clone_arc` / `free_arc`).
pub(crate) struct OwnershipArc;

/// Gives `value` to C as a `*mut C`, to be freed once by [`free_box`].
pub(crate) fn to_boxed_ptr<C: Castable<Ownership = OwnershipBox>>(value: C::RustType) -> *mut C {
    Box::into_raw(Box::new(value)).cast::<C>()
}

/// Gives `value` to C as a `*mut C` holding one reference, given back by [`free_arc`].
pub(crate) fn to_arc_ptr<C: Castable<Ownership = OwnershipArc>>(value: C::RustType) -> *mut C {
    Arc::into_raw(Arc::new(value)).cast_mut().cast::<C>()
}

/// The value behind a pointer from [`to_boxed_ptr`] or [`to_arc_ptr`]; NULL is
/// `NMAT_NULL_ARGUMENT`. (No `try_mut`: a handle that calls change, the tile cache, keeps its
/// state in an `UnsafeCell` reached through this shared reference and guarded by an atomic, so
/// two threads never hold `&mut` to it.)
pub(crate) fn try_ref<'a, C: Castable>(p: *const C) -> Result<&'a C::RustType, nmat_status> {
    arg(p.cast::<C::RustType>())
}

/// A new reference to the value behind a pointer from [`to_arc_ptr`] (NULL and misaligned are
/// statuses), which lives as long as the returned `Arc` even after C frees its own reference.
pub(crate) fn clone_arc<C: Castable<Ownership = OwnershipArc>>(
    p: *const C,
) -> Result<Arc<C::RustType>, nmat_status> {
    let p = p.cast::<C::RustType>();
    check_ptr(p, "pointer argument")?;
    // SAFETY: a non-NULL, aligned `p` came from `to_arc_ptr::<C>` and C still holds its
    // reference (the contract of every function taking the handle), so the count is at least 1
    // while it is incremented and the new reference taken over by `from_raw`.
    unsafe {
        Arc::increment_strong_count(p);
        Ok(Arc::from_raw(p))
    }
}

/// Drops the value behind a pointer from [`to_boxed_ptr`]; NULL is ignored.
pub(crate) fn free_box<C: Castable<Ownership = OwnershipBox>>(p: *mut C) {
    if !p.is_null() {
        // SAFETY: a non-NULL `p` came from `to_boxed_ptr::<C>` and is freed once (the caller's
        // contract of every `*_free` function).
        drop(unsafe { Box::from_raw(p.cast::<C::RustType>()) });
    }
}

/// Gives back C's reference to the value behind a pointer from [`to_arc_ptr`] (the value is
/// dropped with its last reference); NULL is ignored.
pub(crate) fn free_arc<C: Castable<Ownership = OwnershipArc>>(p: *mut C) {
    if !p.is_null() {
        // SAFETY: a non-NULL `p` came from `to_arc_ptr::<C>`, and C gives its reference back once
        // (the caller's contract of every `*_free` function).
        drop(unsafe { Arc::from_raw(p.cast_const().cast::<C::RustType>()) });
    }
}

/// The one null and alignment check of a pointer from C, before any reference or slice is made
/// from it (both must be aligned, even for zero elements). `what` names the pointer in the
/// message.
pub(crate) fn check_ptr<T>(p: *const T, what: &str) -> Result<(), nmat_status> {
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
pub(crate) fn c_type_name<T>() -> &'static str {
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
pub(crate) fn arg<'a, T>(p: *const T) -> Result<&'a T, nmat_status> {
    check_ptr(p, "pointer argument")?;
    // SAFETY: `p` is non-NULL and aligned (checked above), and the C contract of every function
    // taking `p` is that it points to a valid, live `T` for the duration of the call.
    Ok(unsafe { &*p })
}

/// The one null and alignment check for outputs.
pub(crate) fn arg_mut<'a, T>(p: *mut T) -> Result<&'a mut T, nmat_status> {
    check_ptr(p.cast_const(), "output pointer")?;
    // SAFETY: as for `arg`, and the caller does not alias the pointee during the call.
    Ok(unsafe { &mut *p })
}

/// A length no object can have (more than `isize::MAX` bytes): an error, not a slice.
pub(crate) fn check_len<T>(len: usize) -> Result<(), nmat_status> {
    if len.checked_mul(size_of::<T>()).is_none_or(|b| b > isize::MAX as usize) {
        set_last_error(format!("a length of {len} elements is larger than any buffer can be"));
        return Err(NMAT_SIZE_OVERFLOW);
    }
    Ok(())
}

/// The one (pointer, length) → slice conversion (NULL, misaligned and impossible lengths are
/// statuses).
pub(crate) fn slice<'a, T>(p: *const T, len: usize) -> Result<&'a [T], nmat_status> {
    check_ptr(p, "pointer argument")?;
    check_len::<T>(len)?;
    // SAFETY: `p` is non-NULL and aligned and `len` elements fit in `isize::MAX` bytes (checked
    // above); the caller guarantees `len` readable elements at `p` (the documented contract).
    Ok(unsafe { std::slice::from_raw_parts(p, len) })
}

/// [`slice`] for outputs.
pub(crate) fn slice_mut<'a, T>(p: *mut T, len: usize) -> Result<&'a mut [T], nmat_status> {
    check_ptr(p.cast_const(), "output pointer")?;
    check_len::<T>(len)?;
    // SAFETY: as for `slice`, and the caller guarantees `len` writable elements at `p`, not
    // aliased during the call.
    Ok(unsafe { std::slice::from_raw_parts_mut(p, len) })
}
