//! `Context::upload`: a material's buffers, its kernel checked against the CPU on a probe of the
//! material, and the fastest of the exact kernels picked by measurement (docs/GPU.md, "The
//! kernels, and how `upload` picks one").

use crate::cache::{TileDecoder, TileEntry};
use crate::features::Features;
use crate::gpu::{Waits, now};
use crate::layout::words_to_bytes;
use crate::layout::{
    self, ChannelRange, GridRecord, LayerRecord, LevelRecord, NeuralHeader, Quantizer, RequantRow,
    RowConstants, ShaderLayout,
};
use crate::{Context, GpuError, Kernel, TexelRequest, jpeg, matrix, measure, tiled, unrolled};
use nmat_core::{Body, ChannelMask, Material, Neural, TermMode};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use wgpu::util::DeviceExt;

impl Context {
    /// Uploads a parsed material once: the latent words as stored, the int8 weights (widened to
    /// i32 for the reference kernel, packed four per word for the tiled and matrix ones), and per
    /// row the bias and requantization constants derived exactly as the CPU does; and picks its
    /// kernel: of the [`Kernel`]s the device runs, those whose codes on a probe of the material
    /// itself (a few texels of every mip, [`PROBE_TEXELS`] at most) equal the CPU's, the fastest
    /// by measurement (a region decoded through each, timed once per network shape and
    /// `Context`; on a software adapter, which the measuring would cost seconds, the first in
    /// [`Kernel::ALL`] from its end). A kernel whose probe differs is logged (`log::warn!`) and
    /// listed by [`GpuMaterial::rejected`]. The chosen kernel's tile entry (the tile cache's
    /// decode of new tiles) is probed too, on a few whole tiles; where it differs the tiles
    /// decode one texel per invocation ([`GpuMaterial::tile_kernel`], logged). Pipelines are
    /// shared by materials of the same network shape and latent layout (the grids' channels
    /// and bits per code, the levels' terms: the input features are generated for it). Waits
    /// for the probe decodes (a few milliseconds on a GPU); [`Context::upload_async`] awaits
    /// them instead (WebGPU in a browser, where this returns [`GpuError::CannotWait`] for a
    /// neural material).
    pub fn upload(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        m: &Material<'_>,
    ) -> Result<GpuMaterial, GpuError> {
        self.upload_with(device, queue, m, None)
    }

    /// [`Context::upload`] with the kernel chosen by the caller (`None`: the fastest exact one
    /// the device runs), e.g. to compare kernels; [`GpuError::Kernel`] where the device cannot
    /// run it or its codes on the probe differ from the CPU's.
    pub fn upload_with(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        m: &Material<'_>,
        kernel: Option<Kernel>,
    ) -> Result<GpuMaterial, GpuError> {
        // Blocking, every answer the upload awaits is there when asked for.
        now(self.upload_waiting(device, queue, m, kernel, Waits::Block)).unwrap_or_else(|| {
            Err(GpuError::Map("the device left a check of the upload unanswered".into()))
        })
    }

    /// [`Context::upload`] without blocking, for WebGPU in a browser (where the blocking calls
    /// return [`GpuError::CannotWait`]) or an engine that keeps its thread free: the same buffers
    /// and the same checks of each kernel against the CPU on the probe, with the device's answers
    /// (the probes' codes, whether it took each kernel's shader) awaited. The future is ready
    /// once the device has answered, which happens when it is polled: by the browser's event
    /// loop, or natively by the caller's `Device::poll` (e.g. `PollType::Poll` once a frame, or
    /// a thread that polls). No kernel is timed (timing waits for the device): the kernel
    /// chosen is the one [`Context::remember_kernel_choices`] or an earlier [`Context::upload`]
    /// in this `Context` measured fastest for the network's shape, else the first exact one in
    /// [`Kernel::ALL`] from its end, as on a software adapter; [`Context::upload_with_async`]
    /// names one. Nothing times out: a probe that never finishes leaves the future pending (to
    /// give up, drop it, e.g. when a timer of the caller's fires first; the device's queue may
    /// stay busy, as after [`GpuError::Hung`]).
    /// A JPEG material's decode pipelines are built here too (once per `Context`), so that its
    /// decodes can be recorded at once afterwards.
    pub async fn upload_async(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        m: &Material<'_>,
    ) -> Result<GpuMaterial, GpuError> {
        self.upload_with_async(device, queue, m, None).await
    }

    /// [`Context::upload_async`] with the kernel chosen by the caller, as
    /// [`Context::upload_with`].
    pub async fn upload_with_async(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        m: &Material<'_>,
        kernel: Option<Kernel>,
    ) -> Result<GpuMaterial, GpuError> {
        self.upload_waiting(device, queue, m, kernel, Waits::Await).await
    }

    /// The upload, blocking for the device's answers or awaiting them (`waits`).
    async fn upload_waiting(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        m: &Material<'_>,
        kernel: Option<Kernel>,
        waits: Waits,
    ) -> Result<GpuMaterial, GpuError> {
        let n = match m.body() {
            Body::Neural(n) => n,
            Body::Jpeg(j) => {
                // One kernel decodes JPEG materials; asking for a network kernel is an error.
                if let Some(k) = kernel.filter(|&k| k != Kernel::Reference) {
                    return Err(GpuError::Kernel {
                        kernel: k,
                        reason: "a JPEG material has no network",
                    });
                }
                if waits == Waits::Await {
                    self.build_jpeg_pipelines(device, waits).await?;
                }
                let scratch = *self.jpeg_scratch.lock().unwrap_or_else(|e| e.into_inner());
                let (desc, section, maps) = jpeg::upload_words(device, m, j, scratch)?;
                fits_one_binding(device, "descriptors", &desc)?;
                let desc = storage_init(device, "nmat jpeg desc", &desc);
                let section = storage_init(device, "nmat jpeg section", &section);
                let body = GpuBody::Jpeg(maps);
                return Ok(GpuMaterial::new(m, (desc, section), Kernel::Reference, body, None));
            }
        };
        if waits == Waits::Block {
            // Every kernel is checked on a probe read back from the device: where no call can
            // wait for it, say so here (a probe's failure would read as the kernel's).
            crate::gpu::check_can_wait(device)?;
        }
        // The input features for the material's layout, generated once: unchecked in the
        // kernels' sources, checked for the sampling module (features.rs).
        let features = Features::new(n);
        let checked = Arc::<str>::from(features.wgsl(true));
        let (desc, latents) = network_words(m, n, features.key())?;
        fits_one_binding(device, "latents", &latents)?;
        fits_one_binding(device, "descriptors", &desc)?;
        let latents = storage_init(device, "nmat latents", &latents);
        let trial = Trial {
            ctx: self,
            device,
            queue,
            m: (m, n),
            desc,
            latents,
            features: (features.wgsl(false), checked),
            probe: Probe::new(m),
            tables: Default::default(),
            wait: (waits, self.probe_wait(device)),
        };
        let mut rejected = Vec::new();
        let seconds = trial.wait.1.as_secs() as u32;
        if let Some(kernel) = kernel {
            let (gm, entry) = match trial.exact(kernel).await {
                Ok(chosen) => chosen,
                Err(Refusal::Hung) => return Err(GpuError::Hung { kernel, seconds }),
                Err(Refusal::Differs(reason) | Refusal::Cannot(reason)) => {
                    return Err(GpuError::Kernel { kernel, reason });
                }
            };
            return self.with_tile_decoder(device, queue, m, gm, entry, waits).await;
        }
        let software = device.adapter_info().device_type == wgpu::DeviceType::Cpu;
        let key = shape_key(m, n);
        let known = self.choices.lock().unwrap_or_else(|e| e.into_inner()).get(&key).copied();
        // The kernel measured fastest for this shape first, the others only where it fails
        // this material's probe; without a measurement, all that pass, to measure (where the
        // upload can wait for timings).
        let measure = !software && known.is_none() && waits == Waits::Block;
        let order =
            known.into_iter().chain(Kernel::ALL.into_iter().rev().filter(|&k| Some(k) != known));
        let mut candidates = Vec::new();
        for kernel in order {
            match trial.exact(kernel).await {
                Ok(candidate) => {
                    candidates.push(candidate);
                    if !measure {
                        break;
                    }
                }
                Err(Refusal::Hung) => {
                    // Later probes would queue behind it: stop, and say which.
                    log::warn!("nmat-wgpu: the {} kernel's probe did not finish", kernel.name());
                    return Err(GpuError::Hung { kernel, seconds });
                }
                Err(Refusal::Differs(reason)) => {
                    log::warn!("nmat-wgpu: the {} kernel is not used: {reason}", kernel.name());
                    rejected.push((kernel, reason));
                }
                Err(Refusal::Cannot(_)) => {}
            }
        }
        let chosen = if candidates.len() > 1 {
            let out = timing_buffer(device, m);
            // The better of two timings each: a device's first submissions can read slow.
            let time = |gm| self.time_region(device, queue, gm, &out).unwrap_or(f64::INFINITY);
            let times: Vec<f64> = candidates.iter().map(|(gm, _)| time(gm).min(time(gm))).collect();
            self.forget_bindings_of(&out);
            let best =
                (0..candidates.len()).min_by(|&a, &b| times[a].total_cmp(&times[b])).unwrap_or(0);
            let kernel = candidates[best].0.kernel;
            self.choices.lock().unwrap_or_else(|e| e.into_inner()).insert(key, kernel);
            candidates.swap_remove(best)
        } else {
            candidates.pop().ok_or(GpuError::Kernel {
                kernel: Kernel::Reference,
                reason: "no kernel's codes on the probe equal the CPU's",
            })?
        };
        let (gm, entry) = chosen;
        let gm = GpuMaterial { rejected, ..gm };
        self.with_tile_decoder(device, queue, m, gm, entry, waits).await
    }

    /// How long [`Context::upload`] waits for a probe decode on `device`: [`PROBE_WAIT`] (ten
    /// times that on a software adapter, which runs shaders on a loaded CPU), or what a test set.
    pub(crate) fn probe_wait(&self, device: &wgpu::Device) -> Duration {
        let software = device.adapter_info().device_type == wgpu::DeviceType::Cpu;
        let wait = if software { 10 * PROBE_WAIT } else { PROBE_WAIT };
        self.probe_wait.lock().map_or(wait, |w| w.unwrap_or(wait))
    }

    /// Makes [`Context::upload`] wait at most `wait` for each probe decode, so that a test can
    /// see a probe that does not finish in time reported ([`GpuError::Hung`]). For tests only.
    #[doc(hidden)]
    pub fn limit_probe_wait_for_testing(&self, wait: Duration) {
        *self.probe_wait.lock().unwrap_or_else(|e| e.into_inner()) = Some(wait);
    }

    /// Seconds per texel of a region of mip 0 (up to 1024 × 1024 texels, repeated to at least
    /// 2^20 texels) decoded through `gm`'s kernel into `out` ([`timing_buffer`]). (A 512² region
    /// misled on an H200: it ranked the matrix kernel above the reference one, which a 1024²
    /// region decodes faster.)
    fn time_region(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        out: &wgpu::Buffer,
    ) -> Result<f64, GpuError> {
        let region = timing_region(gm.mip_sizes[0]);
        let texels = u64::from(region.2) * u64::from(region.3);
        let repeats = (1u64 << 20).div_ceil(texels).min(64) as u32;
        let (seconds, _) = measure::time_recorded(device, queue, repeats, |encoder| {
            self.record_region(device, encoder, gm, 0, region, ChannelMask::ALL, (out, 0))
                .map(|_| ())
        })?;
        Ok(seconds / texels as f64)
    }

    /// `m` decoded by only `part` of `kernel`'s work (a tiled or matrix kernel,
    /// [`measure::Part`]), to time where the kernel's time goes (`nmat bench --gpu`). Its codes
    /// are **not** the material's: no probe is made, and it must not be used to decode. For
    /// measuring only.
    #[doc(hidden)]
    pub fn upload_part_for_timing(
        &self,
        device: &wgpu::Device,
        m: &Material<'_>,
        kernel: Kernel,
        part: measure::Part,
    ) -> Result<GpuMaterial, GpuError> {
        let Body::Neural(n) = m.body() else { return Err(GpuError::Codec) };
        let refused = |reason| GpuError::Kernel { kernel, reason };
        if kernel == Kernel::Reference {
            return Err(refused("the reference kernel is not split into parts"));
        }
        let features = Features::new(n);
        let (mut desc, latents) = network_words(m, n, features.key())?;
        let prepared = now(self.prepare_part(device, (m, n), kernel, part, &features.wgsl(false)))
            .unwrap_or(Err("the device left its check of the shader unanswered"));
        let (tiled, _, weights) = prepared.map_err(refused)?;
        tiled::append_tables(&mut desc, n, kernel.dot4(), [0, 0]);
        let desc = storage_init(device, "nmat desc (timing)", &desc);
        let latents = storage_init(device, "nmat latents (timing)", &latents);
        let checked = Some(features.wgsl(true).into());
        let gm = GpuMaterial::new(m, (desc, latents), kernel, GpuBody::Neural(tiled), checked);
        Ok(GpuMaterial { weights, ..gm })
    }

    /// The tiled or matrix pipeline of `kernel` for `m` (with `features`, its unchecked
    /// generated input features) and its texels per workgroup (`None`: the reference kernel),
    /// and the entry of its source that can decode the tile cache's new tiles; or why the device
    /// cannot run it.
    async fn prepare(
        &self,
        device: &wgpu::Device,
        m: (&Material<'_>, &Neural<'_>),
        kernel: Kernel,
        features: &str,
    ) -> Result<Prepared, &'static str> {
        self.prepare_part(device, m, kernel, measure::Part::Whole, features).await
    }

    /// [`Context::prepare`] for `part` of the kernel's work (the device's answer on a new
    /// pipeline awaited).
    async fn prepare_part(
        &self,
        device: &wgpu::Device,
        (m, n): (&Material<'_>, &Neural<'_>),
        kernel: Kernel,
        part: measure::Part,
        features: &str,
    ) -> Result<Prepared, &'static str> {
        // The entry point, texels per workgroup and the tile cache's entry (with its workgroups
        // per tile) where the source has one.
        // The matrix kernel's weights where it reads them from storage, made once the device
        // has taken the pipeline.
        let mut storage_weights = None;
        let (source, entry, texels, tiles) = match kernel {
            Kernel::Reference => return Ok((None, None, None)),
            Kernel::Matrix => {
                let emulated = *self.matrix_emulation.lock().unwrap_or_else(|e| e.into_inner());
                let shape = matrix::Shape::new((m, n), device, emulated)?;
                if shape.weights_in_storage() {
                    storage_weights = Some(shape.storage_weights(n));
                }
                let tiles = Some(("matrix_cache", 1));
                (shape.source_part(part, features), "matrix", shape.texels(), tiles)
            }
            Kernel::UnrolledInt32 | Kernel::UnrolledDot4 => {
                let shape = unrolled::Shape::new((m, n), kernel.dot4())?;
                (shape.source_part(part, features), "unrolled", 64, Some(("unrolled_cache", 4)))
            }
            Kernel::Dot4 | Kernel::Int32 => {
                let bytes = device.limits().max_compute_workgroup_storage_size;
                let shape = tiled::Shape::new((m, n), kernel, bytes)
                    .ok_or("the network is too wide for the device's workgroup memory")?;
                let source = shape.source_part(kernel, part, features);
                (source, "tiled", shape.texels, Some(("tiled_cache", 4)))
            }
        };
        let tiles = tiles.filter(|_| part == measure::Part::Whole);
        let tile_entry =
            tiles.map(|(entry, per_tile)| TileEntry { source: source.clone(), entry, per_tile });
        let pipeline = self.kept_pipeline(device, source.clone(), entry).await;
        let refused = match kernel {
            Kernel::Dot4 | Kernel::UnrolledDot4 => {
                "the device refused the shader (its WGSL may lack dot4I8Packed)"
            }
            _ => "the device refused the shader",
        };
        let pipeline = pipeline.ok_or(refused)?;
        let weights = storage_weights.map(|w| self.matrix_weights(device, &w));
        Ok((Some((pipeline, texels)), tile_entry, weights))
    }

    /// The pipeline of `entry` in `source` kept in this context's cache of kernel pipelines
    /// (keyed by the source), else built and kept, refusals too: a kernel's pipeline is
    /// optional, so the device's answer on it is awaited (`Waits::Await`; at once natively).
    pub(crate) async fn kept_pipeline(
        &self,
        device: &wgpu::Device,
        source: String,
        entry: &str,
    ) -> Option<Arc<wgpu::ComputePipeline>> {
        let kept = self.tiled.lock().unwrap_or_else(|e| e.into_inner()).get(&source).cloned();
        if let Some(pipeline) = kept {
            return pipeline;
        }
        let built = self.checked_pipeline(device, &source, entry, Waits::Await).await;
        let built = built.map(Arc::new);
        let mut cache = self.tiled.lock().unwrap_or_else(|e| e.into_inner());
        cache.entry(source).or_insert(built).clone()
    }

    /// The bind group of a matrix kernel's weights in a storage buffer (f16 bits, laid out by
    /// `matrix::Shape::storage_weights`).
    fn matrix_weights(&self, device: &wgpu::Device, weights: &[u16]) -> wgpu::BindGroup {
        // Two f16 a word, the first in the low half (little-endian, as WGSL reads the array).
        let mut words: Vec<u32> = weights
            .chunks(2)
            .map(|p| u32::from(p[0]) | u32::from(p.get(1).copied().unwrap_or(0)) << 16)
            .collect();
        if words.is_empty() {
            words.push(0);
        }
        let buffer = storage_init(device, "nmat matrix weights", &words);
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("nmat matrix weights"),
            layout: &self.weights_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() }],
        })
    }

    /// Makes `kernel`'s uploads compute wrong codes (the last layer's first row requantized to
    /// 0), so that a test can see the probe reject it. For tests only.
    #[doc(hidden)]
    pub fn break_kernel_for_testing(&self, kernel: Kernel) {
        *self.fault.lock().unwrap_or_else(|e| e.into_inner()) = Some(kernel);
    }

    /// Makes the matrix kernel of the materials uploaded from now on emulate its cooperative
    /// matrix operations in scalar code (`matrix_emulated.wgsl`), so that a test can run the
    /// kernel's structure, and check its codes, on a device without matrix units (it needs
    /// `SHADER_F16`): with a row block's products with the high and low bytes through workgroup
    /// memory together (`paired`, `NMAT_WGPU_MATRIX_SUMS=paired`) or one after the other, and
    /// the weights read from a storage buffer (`storage_weights`,
    /// `NMAT_WGPU_MATRIX_WEIGHTS=storage`) or staged in workgroup memory. Exact, but far slower
    /// than the real kernel. For tests only.
    #[doc(hidden)]
    pub fn emulate_matrix_for_testing(&self, paired: bool, storage_weights: bool) {
        let emulation = matrix::Emulation { paired, storage_weights, layout: None, pads: None };
        *self.matrix_emulation.lock().unwrap_or_else(|e| e.into_inner()) = Some(emulation);
    }

    /// With [`Context::emulate_matrix_for_testing`] (called first): the emulated matrix
    /// kernels of the materials uploaded from now on in `layout` (subgroups, texel blocks of 16
    /// per subgroup, batches) with `pads` (activation, weight and product rows), as
    /// `NMAT_WGPU_MATRIX` and `NMAT_WGPU_MATRIX_PAD` ask of the real kernel, so that a test can
    /// check the layouts `scripts/gpu-run.sh` measures. A layout or pads those variables would
    /// not take is ignored (the defaults stay). For tests only.
    #[doc(hidden)]
    pub fn emulate_matrix_layout_for_testing(
        &self,
        layout: (u32, u32, u32),
        pads: (u32, u32, u32),
    ) {
        let mut emulation = self.matrix_emulation.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(e) = emulation.as_mut() {
            e.layout = matrix::valid_layout(layout.into()).then_some(layout);
            e.pads = matrix::valid_pads(pads.into()).then_some(pads);
        }
    }

    /// Gives the JPEG materials uploaded from now on request passes with scratch slots of at
    /// most `words` words (at least one MCU per map), so that a test can see requests decoded
    /// in several rounds. For tests only.
    #[doc(hidden)]
    pub fn limit_jpeg_scratch_for_testing(&self, words: u32) {
        *self.jpeg_scratch.lock().unwrap_or_else(|e| e.into_inner()) = Some(words);
    }
}

/// What [`Context::prepare`] makes of a kernel for a material: its pipeline and texels per
/// workgroup (`None`: the reference kernel), the entry of its source that decodes the tile
/// cache's tiles, and the bind group of its weights where the kernel reads them from storage.
type Prepared = (NetworkPipeline, Option<TileEntry>, Option<wgpu::BindGroup>);

/// A neural material's descriptor with the tiled kernels' tables, and the sampling module's
/// network unrolled on them (`None` where it is not unrolled).
type WithTables = (Vec<u32>, Option<Arc<str>>);

/// A neural material's descriptor words (layout.rs: a [`NeuralHeader`], then the channels'
/// ranges, the grids' records and quantizers, the levels' and layers' records, the weights and
/// row constants; without the tiled and matrix kernels' tables) and its latent words.
fn network_words(
    m: &Material<'_>,
    n: &Neural<'_>,
    features_key: [u32; 2],
) -> Result<(Vec<u32>, Vec<u32>), GpuError> {
    let mlp = n.mlp();
    let mut head = NeuralHeader {
        width: m.width(),
        height: m.height(),
        mip_count: m.mip_count(),
        channel_count: m.channel_count() as u32,
        address_mode: m.address_mode() as u32,
        input_frac_bits: u32::from(mlp.input_frac_bits()),
        pe_frequencies: u32::from(mlp.pe_frequencies()),
        lod_input: u32::from(mlp.lod_code()),
        layer_count: mlp.layers().len() as u32,
        level_count: n.levels().len() as u32,
        grid_count: n.grids().len() as u32,
        ..NeuralHeader::default()
    };
    [head.features_key_lo, head.features_key_hi] = features_key;
    for mip in 0..m.mip_count() {
        head.level_of_mip[mip as usize] = n.level_for_mip(mip) as u32;
    }
    let mut desc = vec![0u32; NeuralHeader::WORDS];
    // Channel ranges (for `nmat_sample`).
    head.ranges_at = desc.len() as u32;
    for ch in m.channels() {
        let range = ChannelRange { min: ch.range_min.to_bits(), max: ch.range_max.to_bits() };
        desc.extend_from_slice(range.words());
    }
    // Grids, then their quantizers.
    let mut latents: Vec<u32> = Vec::new();
    head.grids_at = desc.len() as u32;
    let grids_at = desc.len();
    desc.resize(grids_at + GridRecord::WORDS * n.grids().len(), 0);
    for (g, grid) in n.grids().iter().enumerate() {
        let bits = u64::from(grid.width())
            * u64::from(grid.height())
            * grid.channels() as u64
            * u64::from(grid.bits_per_latent());
        if bits >= 1 << 32 {
            return Err(GpuError::GridTooLarge { grid: g });
        }
        let words: Vec<u32> = grid
            .packed_data()
            .chunks_exact(4)
            .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
            .collect();
        let quant_at = desc.len() as u32;
        for c in 0..grid.channels() {
            let (offset, step) = grid.quantization(c);
            let q = Quantizer { offset: i32::from(offset) as u32, step: i32::from(step) as u32 };
            desc.extend_from_slice(q.words());
        }
        let record = GridRecord {
            width: grid.width(),
            height: grid.height(),
            channels: grid.channels() as u32,
            bits: grid.bits_per_latent(),
            latents_at: latents.len() as u32,
            latent_words: words.len() as u32,
            quant_at,
            pad: 0,
        };
        layout::write(&mut desc, grids_at + GridRecord::WORDS * g, &record);
        latents.extend(words);
    }
    head.levels_at = desc.len() as u32;
    for level in n.levels() {
        let mut record = LevelRecord { term_count: level.terms.len() as u32, ..Default::default() };
        for (term, out) in level.terms.iter().zip(&mut record.terms) {
            out.bilinear = u32::from(term.mode != TermMode::Nearest4);
            out.chain_len = term.grids.len() as u32;
            for (&g, slot) in term.grids.iter().zip(&mut out.grids) {
                *slot = u32::from(g);
            }
        }
        desc.extend_from_slice(record.words());
    }
    // Layers; weights and row constants in `weights`, which follow the records.
    head.layers_at = desc.len() as u32;
    let base = (desc.len() + LayerRecord::WORDS * mlp.layers().len()) as u32;
    let mut weights: Vec<u32> = Vec::new();
    for layer in mlp.layers() {
        let (n_in, n_out) = (layer.inputs(), layer.outputs());
        let weights_at = base + weights.len() as u32;
        for o in 0..n_out {
            weights.extend((0..n_in).map(|i| i32::from(layer.weight_i8(o, i)) as u32));
        }
        let rows_at = base + weights.len() as u32;
        for o in 0..n_out {
            let rq = layer.requant(o);
            let row = RowConstants {
                bias: layer.bias(o) as u32,
                multiplier: rq.multiplier as u32,
                shift: rq.shift,
            };
            weights.extend_from_slice(row.words());
        }
        let record = LayerRecord {
            inputs: n_in as u32,
            outputs: n_out as u32,
            out_frac_bits: u32::from(layer.out_frac_bits()),
            hard_gelu: u32::from(layer.activation() == nmat_core::Activation::HardGelu),
            weights_at,
            rows_at,
            packed_at: 0,
            requant_at: 0,
        };
        desc.extend_from_slice(record.words());
    }
    desc.extend(weights);
    layout::write(&mut desc, 0, &head);
    Ok((desc, latents))
}

/// A new [`GpuMaterial`] id.
fn next_id() -> u64 {
    static NEXT_ID: AtomicU64 = AtomicU64::new(0);
    NEXT_ID.fetch_add(1, Ordering::Relaxed)
}

/// Checks that `words` fit one storage binding (and one buffer) of `device`: past its limits,
/// making the buffer or binding it is a wgpu validation error (handed to the device's error
/// handler), after which every kernel's probe failed and `upload` blamed the kernels.
fn fits_one_binding(
    device: &wgpu::Device,
    what: &'static str,
    words: &[u32],
) -> Result<(), GpuError> {
    let limits = device.limits();
    let limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
    let bytes = 4 * words.len() as u64;
    if bytes > limit {
        return Err(GpuError::DataTooLarge { what, bytes, limit });
    }
    Ok(())
}

/// A storage buffer holding `words`.
fn storage_init(device: &wgpu::Device, label: &str, words: &[u32]) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: &words_to_bytes(words),
        usage: wgpu::BufferUsages::STORAGE,
    })
}

/// How long [`Context::upload`] waits for a kernel's probe decode (a few milliseconds on a GPU)
/// before it reports the kernel as hung ([`GpuError::Hung`]) instead of waiting for ever; ten
/// times as long on a software adapter.
pub const PROBE_WAIT: Duration = Duration::from_secs(20);

/// The most texels [`Context::upload`] decodes to check a kernel against the CPU.
pub const PROBE_TEXELS: usize = 1024;

/// The texels a kernel decodes before it is used for a material, and the CPU's codes of them:
/// the first 8 × 8 texels of mip 0 and up to 8 × 8 spread over every mip (the edges included),
/// all channels.
struct Probe {
    requests: Vec<TexelRequest>,
    codes: Vec<u8>,
}

impl Probe {
    fn new(m: &Material<'_>) -> Probe {
        let mut requests: Vec<TexelRequest> =
            (0..64).map(|i| TexelRequest { x: i % 8, y: i / 8, mip: 0 }).collect();
        for mip in 0..m.mip_count() {
            let (w, h) = m.mip_size(mip);
            let at = |k: u32, size: u32| (u64::from(k) * u64::from(size - 1) / 7) as i32;
            for k in 0..64 {
                let r = TexelRequest { x: at(k % 8, w), y: at(k / 8, h), mip };
                if !requests.contains(&r) && requests.len() < PROBE_TEXELS {
                    requests.push(r);
                }
            }
        }
        let mut codes = Vec::with_capacity(requests.len() * m.channel_count());
        let mut texel = [0u8; 16];
        for r in &requests {
            let n = m
                .decode_texel_u8(
                    i64::from(r.x),
                    i64::from(r.y),
                    r.mip,
                    ChannelMask::ALL,
                    &mut texel,
                )
                .unwrap_or(0);
            codes.extend_from_slice(&texel[..n]);
        }
        Probe { requests, codes }
    }
}

/// What a kernel is tried on at upload: the material, its buffers and descriptor words, the
/// probe, and how the probe's codes are waited for.
struct Trial<'a> {
    ctx: &'a Context,
    device: &'a wgpu::Device,
    queue: &'a wgpu::Queue,
    m: (&'a Material<'a>, &'a Neural<'a>),
    /// The descriptor without the tiled kernels' tables, and the latents' buffer.
    desc: Vec<u32>,
    latents: wgpu::Buffer,
    /// The generated input features: unchecked (the kernels' sources), checked (the sampling
    /// module's).
    features: (String, Arc<str>),
    probe: Probe,
    /// The descriptor with the tiled kernels' tables and the sampling module's network
    /// unrolled on them, made once per kind of table (with 128 · Σ w in the bias for the dot4
    /// kernels, without for the others) for all the candidates.
    tables: [std::sync::OnceLock<WithTables>; 2],
    /// Blocking (at most the duration for each probe) or awaiting.
    wait: (Waits, Duration),
}

/// Why a kernel tried at upload is not used.
enum Refusal {
    /// Its codes on the probe differ from the CPU's (logged and listed by
    /// [`GpuMaterial::rejected`]).
    Differs(&'static str),
    /// Its probe did not finish within the wait.
    Hung,
    /// The device cannot run it, or its probe decode failed.
    Cannot(&'static str),
}

impl Trial<'_> {
    /// `kernel`, prepared and checked against the CPU on the probe.
    async fn exact(&self, kernel: Kernel) -> Result<(GpuMaterial, Option<TileEntry>), Refusal> {
        let Trial { ctx, device, m: (m, n), .. } = *self;
        let (tiled, tile_entry, weights) =
            ctx.prepare(device, (m, n), kernel, &self.features.0).await.map_err(Refusal::Cannot)?;
        let (mut desc, network) = match kernel {
            Kernel::Reference => (self.desc.clone(), None),
            _ => self.with_tables(kernel.dot4()).clone(),
        };
        if *ctx.fault.lock().unwrap_or_else(|e| e.into_inner()) == Some(kernel) {
            break_last_row(&mut desc);
        }
        if fits_one_binding(device, "descriptors", &desc).is_err() {
            let reason = "its descriptors with tables exceed one storage binding of the device";
            return Err(Refusal::Cannot(reason));
        }
        let desc = storage_init(device, "nmat desc", &desc);
        let body = GpuBody::Neural(tiled);
        let checked = Some(self.features.1.clone());
        let gm = GpuMaterial::new(m, (desc, self.latents.clone()), kernel, body, checked);
        let gm = GpuMaterial { network, weights, ..gm };
        let failed = Refusal::Cannot("the probe decode failed");
        let pending = ctx
            .submit_requests(device, self.queue, &gm, &self.probe.requests, ChannelMask::ALL)
            .map_err(|_| failed)?;
        let codes = match self.wait {
            (Waits::Block, wait) => pending.wait_within(device, wait),
            (Waits::Await, _) => pending.wait_async().await.map(Some),
        };
        match codes {
            Ok(Some(codes)) if codes == self.probe.codes => Ok((gm, tile_entry)),
            Ok(Some(_)) => Err(Refusal::Differs("its codes on the probe differ from the CPU's")),
            Ok(None) => Err(Refusal::Hung),
            Err(_) => Err(Refusal::Cannot("the probe decode failed")),
        }
    }

    /// The descriptor with the tiled kernels' tables (`dot4`: with 128 · Σ w in the bias) and
    /// the sampling module's network unrolled on them.
    fn with_tables(&self, dot4: bool) -> &WithTables {
        let (m, n) = self.m;
        self.tables[usize::from(dot4)].get_or_init(|| {
            let sample = unrolled::SampleNetwork::new((m, n), dot4);
            let key = sample.as_ref().map_or([0, 0], |s| s.key());
            let mut desc = self.desc.clone();
            tiled::append_tables(&mut desc, n, dot4, key);
            (desc, sample.map(|s| Arc::<str>::from(s.wgsl())))
        })
    }
}

/// The last layer's first row of a descriptor requantized to 0 (multiplier 0), in the reference
/// kernel's rows and the tiled kernels' row table: [`Context::break_kernel_for_testing`].
fn break_last_row(desc: &mut [u32]) {
    let head: NeuralHeader = layout::read(desc, 0);
    let Some(last) = head.layer_count.checked_sub(1) else { return };
    let record: LayerRecord =
        layout::read(desc, (head.layers_at + LayerRecord::WORDS as u32 * last) as usize);
    let rows = record.rows_at as usize;
    let mut row: RowConstants = layout::read(desc, rows);
    row.multiplier = 0;
    layout::write(desc, rows, &row);
    if record.requant_at != 0 {
        // m = 0, and the 32-bit path's u = 1, m' = 0, m'/2^u = 0.0.
        let at = record.requant_at as usize;
        let table: RequantRow = layout::read(desc, at);
        layout::write(desc, at, &RequantRow { m: 0, u: 1, mp: 0, c: 0, ..table });
    }
}

/// What the kernel measured fastest is remembered by: the network's widths and channels.
fn shape_key(m: &Material<'_>, n: &Neural<'_>) -> String {
    let widths: Vec<(usize, usize)> =
        n.mlp().layers().iter().map(|l| (l.inputs(), l.outputs())).collect();
    format!("{widths:?} {}", m.channel_count())
}

/// The region of mip 0 `upload` times each kernel on: up to 1024 × 1024 texels.
fn timing_region((w, h): (u32, u32)) -> (u32, u32, u32, u32) {
    (0, 0, w.min(1024), h.min(1024))
}

/// The output of `Context::time_region` for `m`, shared by every kernel's timing.
fn timing_buffer(device: &wgpu::Device, m: &Material<'_>) -> wgpu::Buffer {
    let (_, _, w, h) = timing_region(m.mip_size(0));
    let bytes = u64::from(w) * u64::from(h) * m.channel_count() as u64;
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("nmat kernel timing"),
        size: bytes.next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    })
}

impl GpuMaterial {
    /// `m` on the GPU: its descriptor and latent (or JPEG section) buffers, decoded by `kernel`.
    fn new(
        m: &Material<'_>,
        (desc, latents): (wgpu::Buffer, wgpu::Buffer),
        kernel: Kernel,
        body: GpuBody,
        features: Option<Arc<str>>,
    ) -> GpuMaterial {
        GpuMaterial {
            id: next_id(),
            desc,
            latents,
            channel_count: m.channel_count(),
            mip_sizes: (0..m.mip_count()).map(|mip| m.mip_size(mip)).collect(),
            address_clamp: m.address_mode() == nmat_core::AddressMode::Clamp,
            ranges: m.channels().iter().map(|c| (c.range_min, c.range_max)).collect(),
            constant_codes: m.channels().iter().map(|c| c.constant_code()).collect(),
            kernel,
            rejected: Vec::new(),
            body,
            tile_decoder: None,
            features,
            network: None,
            weights: None,
        }
    }
}

/// A material's buffers on the GPU.
pub struct GpuMaterial {
    /// Unique per upload: which material a cached bind group binds.
    pub(crate) id: u64,
    pub(crate) desc: wgpu::Buffer,
    pub(crate) latents: wgpu::Buffer,
    pub(crate) channel_count: usize,
    pub(crate) mip_sizes: Vec<(u32, u32)>,
    /// Clamp (true) or wrap addressing, and each channel's range (min, max): for the tile cache.
    pub(crate) address_clamp: bool,
    pub(crate) ranges: Vec<(f32, f32)>,
    /// Per channel: the code of a constant channel (`Channel::constant_code`), which BC
    /// transcoding uses instead of the decoded one, as the CPU does.
    pub(crate) constant_codes: Vec<Option<u8>>,
    pub(crate) kernel: Kernel,
    /// Kernels whose codes on the upload's probe differed from the CPU's, and why.
    pub(crate) rejected: Vec<(Kernel, &'static str)>,
    pub(crate) body: GpuBody,
    /// The entry of its kernel that decodes the tile cache's new tiles, checked against the CPU
    /// at upload; `None`: one texel per invocation (cache_decode.wgsl, or JPEG's MCU kernel).
    pub(crate) tile_decoder: Option<TileDecoder>,
    /// A neural material's input features generated for its latent layout, checked
    /// (features.rs), for [`crate::SampleBindings::module_for`]; `None` for a JPEG material.
    pub(crate) features: Option<Arc<str>>,
    /// Its network unrolled on the tables its descriptor holds, checked (unrolled.rs,
    /// `SampleNetwork`), for [`crate::SampleBindings::module_for`]; `None` where the descriptor
    /// has no tables (the reference kernel's materials), the network is not unrolled, or JPEG.
    pub(crate) network: Option<Arc<str>>,
    /// The bind group of its matrix kernel's weights in a storage buffer (group 1,
    /// `matrix::WEIGHTS_GROUP`), where its kernel reads them from there; else `None`.
    pub(crate) weights: Option<wgpu::BindGroup>,
}

/// The tiled or matrix kernel's pipeline and texels per workgroup (`None`: the reference
/// kernel).
pub(crate) type NetworkPipeline = Option<(Arc<wgpu::ComputePipeline>, u32)>;

/// What decodes a material's texels on the GPU, by codec: matched where a decode starts.
pub(crate) enum GpuBody {
    /// A neural material: the pipeline of its kernel.
    Neural(NetworkPipeline),
    /// A JPEG material's maps (`desc` and `latents` then hold its descriptor and section).
    Jpeg(jpeg::JpegMaps),
}

impl GpuMaterial {
    pub fn channel_count(&self) -> usize {
        self.channel_count
    }
    /// The kernel that decodes this material's regions and requests.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }
    /// Texels a workgroup of its kernel decodes (`None`: the reference kernel, 64 a workgroup
    /// one per invocation; and JPEG materials, an MCU a workgroup).
    pub fn workgroup_texels(&self) -> Option<u32> {
        match &self.body {
            GpuBody::Neural(Some((_, texels))) => Some(*texels),
            _ => None,
        }
    }
    /// The kernel that decodes this material's new tiles in a [`crate::GpuTileCache`]: its own
    /// tiled or matrix kernel, through that kernel's tile entry, where the entry decoded the
    /// upload's probe tiles as the CPU does ([`Context::upload`]); else [`Kernel::Reference`]
    /// (one texel per invocation; also for JPEG materials, whose tiles the JPEG kernel decodes).
    pub fn tile_kernel(&self) -> Kernel {
        if self.tile_decoder.is_some() { self.kernel } else { Kernel::Reference }
    }
    /// The kernels [`Context::upload`] did not use because their codes on its probe differed
    /// from the CPU's (a driver that computes differently), with the reason; usually empty.
    pub fn rejected(&self) -> &[(Kernel, &'static str)] {
        &self.rejected
    }
    /// Width and height of each mip.
    pub fn mip_sizes(&self) -> &[(u32, u32)] {
        &self.mip_sizes
    }
    /// The material's codec. A JPEG material decodes through regions and requests (submitted or
    /// recorded), into textures, into BC blocks and through the tile cache; `nmat_sample`
    /// refuses it with [`GpuError::Codec`].
    pub fn codec(&self) -> nmat_core::Codec {
        match self.body {
            GpuBody::Neural(_) => nmat_core::Codec::Neural,
            GpuBody::Jpeg(_) => nmat_core::Codec::Jpeg,
        }
    }
    /// [`GpuError::Codec`] for a JPEG material (paths that decode neural materials only).
    pub(crate) fn neural(&self) -> Result<(), GpuError> {
        match self.body {
            GpuBody::Neural(_) => Ok(()),
            GpuBody::Jpeg(_) => Err(GpuError::Codec),
        }
    }
}
