//! The one panic boundary. Every exported function runs its body inside [`boundary`] (those that
//! return a status through `status::guard`, built on it): a panic — a bug in nmat, never caller
//! input — must not unwind into C, which is undefined behaviour, so it ends here as the value the
//! return type gives for it ([`OnPanic`]: `NMAT_INTERNAL_ERROR` with a message, 0, or nothing).

use std::panic::{AssertUnwindSafe, catch_unwind};

/// What an exported function returns when its body panicked.
pub(crate) trait OnPanic {
    fn on_panic() -> Self;
}

impl OnPanic for () {
    fn on_panic() {}
}

/// A size or count: 0, which every function returning one documents as "nothing" or "unknown".
impl OnPanic for usize {
    fn on_panic() -> usize {
        0
    }
}

/// A version number: 0, which no release of this library has.
impl OnPanic for u32 {
    fn on_panic() -> u32 {
        0
    }
}

/// Runs `f`; a panic inside it gives [`OnPanic::on_panic`] instead of unwinding further.
pub(crate) fn boundary<T: OnPanic>(f: impl FnOnce() -> T) -> T {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|_| T::on_panic())
}
