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
/// stderr which adapter does `what` ("decoding", "transcoding"); then, on stderr too, how long
/// opening the device and the upload took (the upload compiles, checks and times the kernels:
/// docs/GPU.md) and which kernel decodes — the fixed cost of a `--gpu` command, apart from its
/// decoding.
pub fn upload(
    m: &nmat_core::Material<'_>,
    what: &str,
) -> Result<(wgpu::Device, wgpu::Queue, nmat_wgpu::Context, nmat_wgpu::GpuMaterial)> {
    let start = std::time::Instant::now();
    let (device, queue, info) = open()?;
    let opened = start.elapsed().as_secs_f64();
    eprintln!("{what} on {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    let ctx = nmat_wgpu::Context::new(&device);
    let gm = ctx.upload(&device, &queue, m)?;
    let uploaded = start.elapsed().as_secs_f64() - opened;
    let kernel = match gm.codec() {
        nmat_core::Codec::Jpeg => "JPEG",
        nmat_core::Codec::Neural => gm.kernel().name(),
    };
    eprintln!(
        "  device opened in {opened:.3} s, material uploaded in {uploaded:.3} s; the {kernel} \
         kernel decodes it"
    );
    Ok((device, queue, ctx, gm))
}
