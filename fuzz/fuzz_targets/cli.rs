//! The `nmat` command's input paths that need no training (`nmat_cli::exercise_untrusted`: .nmat
//! header checks, SOURCE_MAPS, `nmat info`, `nmat decode`'s plan and maps, map images under a
//! memory budget) on any bytes: never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| nmat_cli::exercise_untrusted(data));
