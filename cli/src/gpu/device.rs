//! The GPU every `--gpu` path runs on: wgpu's default adapter.

use crate::common::Result;
use nmat_wgpu::wgpu;

/// What `--gpu` says where wgpu finds no adapter.
const NO_ADAPTER: &str =
    "--gpu: no GPU adapter found (on Linux without a GPU: apt-get install mesa-vulkan-drivers)";

/// The default adapter's device, or `None` where wgpu finds none.
pub fn find() -> Option<(wgpu::Device, wgpu::Queue, wgpu::AdapterInfo)> {
    pollster::block_on(nmat_wgpu::default_device())
}

/// The default adapter's device, or an error saying that there is none.
pub fn open() -> Result<(wgpu::Device, wgpu::Queue, wgpu::AdapterInfo)> {
    Ok(find().ok_or(NO_ADAPTER)?)
}

/// The default adapter's device and queue, a context on it and `m` uploaded, after saying on
/// stderr which adapter does `what` ("decoding", "transcoding").
pub fn upload(
    m: &nmat_core::Material<'_>,
    what: &str,
) -> Result<(wgpu::Device, wgpu::Queue, nmat_wgpu::Context, nmat_wgpu::GpuMaterial)> {
    let (device, queue, info) = open()?;
    eprintln!("{what} on {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    let ctx = nmat_wgpu::Context::new(&device);
    let gm = ctx.upload(&device, &queue, m)?;
    Ok((device, queue, ctx, gm))
}
