//! [`default_device`]: a device for tools and tests, with what the kernels can use.

use crate::context::IMMEDIATE_BYTES;
use crate::{MATRIX_FEATURES, matrix_usable, measure};

/// Creates a device on the first adapter wgpu finds (any backend, software adapters included),
/// with downlevel limits only. For tools and tests; engines pass their own device.
pub async fn default_device() -> Option<(wgpu::Device, wgpu::Queue, wgpu::AdapterInfo)> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = instance
        .request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        })
        .await
        .ok()?;
    let info = adapter.get_info();
    // Cooperative matrices (the matrix kernel) where the adapter has the configuration it uses.
    let matrices = adapter.features().contains(MATRIX_FEATURES)
        && matrix_usable(&adapter.cooperative_matrix_properties());
    // Immediates (dispatch parameters with no buffer per call) where there is room for them.
    let immediates = adapter.features().contains(wgpu::Features::IMMEDIATES)
        && adapter.limits().max_immediate_size >= IMMEDIATE_BYTES;
    let (device, queue) = adapter
        .request_device(&wgpu::DeviceDescriptor {
            label: Some("nmat"),
            // BC textures (for transcoded blocks), timestamp queries (for measuring), the
            // adapter's own format features (R8Unorm storage textures), immediates and
            // cooperative matrices where the adapter has them, nothing else.
            required_features: adapter.features()
                & (wgpu::Features::TEXTURE_COMPRESSION_BC
                    | measure::TIMESTAMP_FEATURES
                    | wgpu::Features::TEXTURE_ADAPTER_SPECIFIC_FORMAT_FEATURES)
                | if matrices { MATRIX_FEATURES } else { wgpu::Features::empty() }
                | if immediates { wgpu::Features::IMMEDIATES } else { wgpu::Features::empty() },
            // Downlevel limits, but all the workgroup memory the adapter has (the tiled kernel
            // decodes more texels per workgroup with more) and up to 8 storage buffers per
            // shader stage (the matrix kernel with its weights in storage binds 5).
            required_limits: wgpu::Limits {
                max_compute_workgroup_storage_size: adapter
                    .limits()
                    .max_compute_workgroup_storage_size,
                max_storage_buffers_per_shader_stage: storage_buffers(&adapter),
                max_immediate_size: if immediates { IMMEDIATE_BYTES } else { 0 },
                ..wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits())
            },
            experimental_features: if matrices {
                experimental()
            } else {
                wgpu::ExperimentalFeatures::disabled()
            },
            memory_hints: wgpu::MemoryHints::MemoryUsage,
            trace: wgpu::Trace::Off,
        })
        .await
        .ok()?;
    Some((device, queue, info))
}

/// The storage buffers per shader stage to ask `adapter` for: up to 8 where it has them, at
/// least the downlevel 4.
fn storage_buffers(adapter: &wgpu::Adapter) -> u32 {
    let downlevel = wgpu::Limits::downlevel_defaults().max_storage_buffers_per_shader_stage;
    adapter.limits().max_storage_buffers_per_shader_stage.clamp(downlevel, 8)
}

/// wgpu's consent token for its experimental features, which the matrix kernel's cooperative
/// matrices are.
#[allow(unsafe_code)]
fn experimental() -> wgpu::ExperimentalFeatures {
    // SAFETY: wgpu asks its caller to accept that an experimental feature may have bugs. The
    // only experimental feature enabled is EXPERIMENTAL_COOPERATIVE_MATRIX, used only by the
    // matrix kernel, whose results `Context::upload` compares with the CPU's before using it.
    unsafe { wgpu::ExperimentalFeatures::enabled() }
}
