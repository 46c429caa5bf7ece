//! A memory hint for the trainer's random reads (latents, target texels, optimizer state): the
//! address is known some work before the value is needed.
#![allow(unsafe_code)]

/// Asks the CPU to bring the cache line holding `slice[i]` into the L1 cache. Changes no value;
/// a no-op when `i` is out of range or the target has no hint.
#[inline(always)]
pub fn prefetch<T>(slice: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v) = slice.get(i) {
        use core::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: SSE is part of x86-64, and a prefetch reads nothing and never faults (`v` is a
        // valid reference in any case).
        unsafe { _mm_prefetch::<_MM_HINT_T0>((v as *const T).cast()) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (slice, i);
}
