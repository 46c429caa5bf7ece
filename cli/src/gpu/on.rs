//! The GPU paths of a `--features gpu` build, through nmat-wgpu.

use super::{BenchRow, Levels, Walk, device};
use crate::args::GpuKernelArg;
use crate::common::Result;
use crate::corridor::Options as WalkOptions;
use nmat_cli::output;
use nmat_cli::stats::median_seconds;
use nmat_core::Material;
use nmat_core::bc::BcFormat;
use nmat_wgpu::Kernel;
use std::path::{Path, PathBuf};

/// `nmat decode --gpu`: the maps of `plan` decoded on the GPU and written to `dir` (kernel
/// choices kept in `choices`, `--kernel-choices`).
pub fn decode_maps(
    m: &Material<'_>,
    plan: &output::DecodePlan,
    dir: &Path,
    progress: &mut dyn FnMut(u64),
    choices: Option<&Path>,
) -> Result<Vec<PathBuf>> {
    let (device, queue, ctx, gm) = device::upload(m, "decoding", choices)?;
    // Every mip submitted before the first is waited for (each wait waits for its own
    // submission only): the GPU decodes the next mips while the previous ones are written.
    let all = nmat_core::ChannelMask::ALL;
    let mut pending = std::collections::HashMap::new();
    for &mip in plan.mips() {
        let (w, h) = m.mip_size(mip);
        pending.insert(mip, ctx.submit_region(&device, &queue, &gm, mip, (0, 0, w, h), all)?);
    }
    let pending = std::cell::RefCell::new(pending);
    let decode = |mip: u32| -> Result<Vec<u8>> {
        match pending.borrow_mut().remove(&mip) {
            Some(submitted) => Ok(submitted.wait(&device)?),
            None => Ok(ctx.decode_mip(&device, &queue, &gm, mip, all)?),
        }
    };
    let with = output::DecodeWith { float: false, batch: Some(&decode) };
    output::write_maps(m, plan, dir, with, progress)
}

/// Whether nmat-wgpu encodes `format` (the others are encoded on the CPU).
pub fn encodes(format: BcFormat) -> bool {
    nmat_wgpu::encodes(format)
}

/// `nmat transcode --gpu`: the transcoder of `m`'s textures on the GPU (kernel choices kept in
/// `choices`, `--kernel-choices`).
pub fn transcoder(m: &Material<'_>, choices: Option<&Path>) -> Result<Levels> {
    let (device, queue, ctx, gm) = device::upload(m, "transcoding", choices)?;
    Ok(Box::new(move |textures, progress| {
        let on_gpu: Vec<_> = textures.iter().copied().filter(|t| encodes(t.format)).collect();
        let mut levels: Vec<Vec<Vec<u8>>> = vec![Vec::new(); on_gpu.len()];
        if !on_gpu.is_empty() {
            // Per mip, every texture from one decode and one submission; every mip submitted
            // before the first wait, so the GPU runs them back to back.
            let mut pending = Vec::new();
            for mip in 0..gm.mip_sizes().len() {
                pending.push(
                    ctx.submit_transcode_textures(&device, &queue, &gm, &on_gpu, mip as u32)?,
                );
            }
            for (mip_pending, &(w, h)) in pending.into_iter().zip(gm.mip_sizes()) {
                for (texture_levels, mip_blocks) in
                    levels.iter_mut().zip(mip_pending.wait(&device)?)
                {
                    texture_levels.push(mip_blocks);
                }
                progress(u64::from(w) * u64::from(h));
            }
        }
        let mut levels = levels.into_iter();
        Ok(textures.iter().map(|t| if encodes(t.format) { levels.next() } else { None }).collect())
    }))
}

/// The GPU row of `nmat bench`'s CPU table (median of 5 runs): a real GPU decodes the whole mip
/// 0; a software adapter (lavapipe, on a machine without a GPU) only the bench's region `side` of
/// it — the whole mip of a 1024² material takes it minutes.
pub fn bench_row(m: &Material<'_>, side: (u32, u32), row: &BenchRow<'_>) -> Result<()> {
    let Some((device, queue, info)) = device::find() else {
        println!("  GPU: no adapter found");
        return Ok(());
    };
    let ctx = nmat_wgpu::Context::new(&device);
    let gm = ctx.upload(&device, &queue, m)?;
    let all = nmat_core::ChannelMask::ALL;
    if info.device_type == nmat_wgpu::DeviceType::Cpu {
        let what = format!("GPU {} (a software rasterizer on the CPU)", info.name);
        let secs = median_seconds(5, || -> Result<()> {
            ctx.submit_region(&device, &queue, &gm, 0, (0, 0, side.0, side.1), all)?
                .wait(&device)?;
            Ok(())
        })?;
        let scope = format!("region {}×{} only: software adapter", side.0, side.1);
        row(&what, secs, u64::from(side.0) * u64::from(side.1), &scope);
    } else {
        let what = format!("GPU {}", info.name);
        let secs = median_seconds(5, || -> Result<()> {
            ctx.decode_mip(&device, &queue, &gm, 0, all)?;
            Ok(())
        })?;
        let (w, h) = m.mip_size(0);
        row(&what, secs, u64::from(w) * u64::from(h), "whole mip 0");
    }
    Ok(())
}

/// `nmat bench --gpu`'s table for `m` (docs/GPU.md, "Measured"), through `kernel` only where
/// given.
pub fn bench_table(
    m: &Material<'_>,
    region: u32,
    runs: usize,
    kernel: Option<GpuKernelArg>,
) -> Result<()> {
    super::bench::table(m, region, runs, kernel.map(kernel_of))
}

/// The kernel `--kernel` names (its value is the kernel's `Kernel::id`).
fn kernel_of(arg: GpuKernelArg) -> Kernel {
    match arg {
        GpuKernelArg::Reference => Kernel::Reference,
        GpuKernelArg::UnrolledI32 => Kernel::UnrolledInt32,
        GpuKernelArg::UnrolledDot4 => Kernel::UnrolledDot4,
        GpuKernelArg::I32 => Kernel::Int32,
        GpuKernelArg::Dot4 => Kernel::Dot4,
        GpuKernelArg::Matrix => Kernel::Matrix,
    }
}

/// `nmat walk --gpu`: the walk through nmat-wgpu's tile cache.
pub fn walk(opts: &WalkOptions, materials: &[Material<'_>], mips: bool) -> Result<Walk> {
    super::walk::walk(opts, materials, mips)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    /// `--kernel`'s values are the names nmat-wgpu writes and reads (`Kernel::id`), one per
    /// kernel.
    #[test]
    fn kernel_arguments_are_the_kernels_ids() {
        let args = GpuKernelArg::value_variants();
        assert_eq!(args.len(), Kernel::ALL.len());
        for arg in args {
            let value = arg.to_possible_value().map(|v| v.get_name().to_owned());
            assert_eq!(value.as_deref(), Some(kernel_of(*arg).id()), "{arg:?}");
        }
    }
}
