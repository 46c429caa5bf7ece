//! The GPU paths of a build without the `gpu` feature: each says how to build a `nmat` that
//! has them.

use super::{BenchRow, Levels, Walk};
use crate::args::GpuKernelArg;
use crate::common::Result;
use crate::corridor::Options as WalkOptions;
use nmat_cli::output;
use nmat_core::Material;
use nmat_core::bc::BcFormat;
use std::path::{Path, PathBuf};

/// What `--gpu` says in a build without the `gpu` feature.
const NO_GPU_BUILD: &str =
    "--gpu: this nmat was built without GPU support; build it with `--features gpu`";

pub fn decode_maps(
    _: &Material<'_>,
    _: &output::DecodePlan,
    _: &Path,
    _: &mut dyn FnMut(u64),
    _: Option<&Path>,
) -> Result<Vec<PathBuf>> {
    Err(NO_GPU_BUILD.into())
}

pub fn encodes(_: BcFormat) -> bool {
    false
}

pub fn transcoder(_: &Material<'_>, _: Option<&Path>) -> Result<Levels> {
    Err(NO_GPU_BUILD.into())
}

pub fn bench_row(_: &Material<'_>, _: (u32, u32), _: &BenchRow<'_>) -> Result<()> {
    println!("  GPU: not measured (build with --features gpu)");
    Ok(())
}

pub fn bench_table(_: &Material<'_>, _: u32, _: usize, _: Option<GpuKernelArg>) -> Result<()> {
    Err(NO_GPU_BUILD.into())
}

pub fn walk(_: &WalkOptions, _: &[Material<'_>], _: bool) -> Result<Walk> {
    Err(NO_GPU_BUILD.into())
}
