//! Memory hints for the trainer's random reads (latents, target texels, optimizer state): the
//! address of a read is known some work before its value is needed, and the arrays it reads are
//! large. Hints change no value.
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

/// `n` copies of `value` in memory the kernel is asked to back with huge pages (Linux
/// transparent huge pages, `madvise` mode included). The trainer reads tens of MiB at random;
/// with 4 KiB pages nearly every such read also misses the TLB. Elsewhere a plain vector.
pub fn huge_vec<T: Clone>(n: usize, value: T) -> Vec<T> {
    let mut v: Vec<T> = Vec::with_capacity(n);
    #[cfg(target_os = "linux")]
    advise_huge_pages(v.as_ptr().cast(), n * std::mem::size_of::<T>());
    v.resize(n, value);
    v
}

/// Advises huge pages for the 2 MiB-aligned part of `[start, start + len)` (smaller blocks
/// cannot have one). Called before the memory is first written, so its pages are born huge.
#[cfg(target_os = "linux")]
fn advise_huge_pages(start: *const u8, len: usize) {
    const HUGE: usize = 2 << 20;
    let (begin, end) =
        ((start as usize).next_multiple_of(HUGE), (start as usize + len) & !(HUGE - 1));
    if end > begin {
        // SAFETY: the range lies inside an allocation this process owns (a vector's capacity),
        // starts on a page boundary, and MADV_HUGEPAGE changes no contents or permissions; a
        // kernel without transparent huge pages answers EINVAL, which is ignored.
        unsafe { libc::madvise(begin as *mut libc::c_void, end - begin, libc::MADV_HUGEPAGE) };
    }
}
