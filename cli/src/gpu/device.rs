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
