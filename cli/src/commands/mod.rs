//! One module per command, each with a `run` that takes the command's arguments (`args`).
//! Shared work is below them (`common`, `reference`, `corridor`, the GPU seam `gpu`, and the
//! `nmat_cli` library); no command calls another.

pub mod bench;
pub mod bench_train;
pub mod build;
pub mod decode;
pub mod demo;
pub mod encode;
pub mod eval;
pub mod index;
pub mod info;
pub mod pack;
pub mod transcode;
pub mod walk;
