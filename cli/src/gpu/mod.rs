//! The one place where the `gpu` feature makes a difference. Every GPU path of the command —
//! `decode --gpu`, `transcode --gpu`, `bench`'s GPU row and `bench --gpu`, `walk --gpu` — has the
//! same signature in both builds: `on` runs it through nmat-wgpu, `off` says how to build a
//! `nmat` that has it (or, for `bench`'s row, that it was not measured).

use crate::common::Result;
use crate::corridor::Row;

#[cfg(feature = "gpu")]
mod bench;
#[cfg(feature = "gpu")]
mod device;
#[cfg(not(feature = "gpu"))]
mod off;
#[cfg(feature = "gpu")]
mod on;
#[cfg(feature = "gpu")]
mod walk;

#[cfg(not(feature = "gpu"))]
pub use off::*;
#[cfg(feature = "gpu")]
pub use on::*;

/// Whether this build has the GPU paths (the `gpu` feature).
pub const BUILT: bool = cfg!(feature = "gpu");

/// Every mip of each texture transcoded on the GPU, one decode of the chain for all of them
/// (`None` for a texture whose format the GPU does not encode), reporting texels done.
pub type Levels = Box<
    dyn Fn(&[nmat_core::bc::BcTexture], &mut dyn FnMut(u64)) -> Result<Vec<Option<Vec<Vec<u8>>>>>,
>;

/// What [`bench_row`] reports a measurement to: adapter, seconds, texels, what was decoded.
pub type BenchRow<'a> = dyn Fn(&str, f64, u64, &str) + 'a;

/// `nmat walk --gpu`'s result: the adapter, and the walk's rows with the clock that timed them.
pub struct Walk {
    pub adapter: String,
    /// A software rasterizer on the CPU (lavapipe): not a GPU's numbers.
    pub software: bool,
    pub clock: &'static str,
    /// Per material, the kernel that decodes its new tiles (`GpuMaterial::tile_kernel`).
    pub tile_kernels: Vec<&'static str>,
    pub rows: Vec<Row>,
}
