//! wgpu plumbing every family of passes shares: bind group layout entries, pipelines the device
//! may refuse, dispatches past the per-dimension limit, the checks of a caller's buffers, reading
//! a buffer back.

use crate::GpuError;
use std::sync::{Mutex, mpsc};
use wgpu::util::DeviceExt;

/// Texels per workgroup of the reference decode kernel.
pub(crate) const WORKGROUP: u32 = 64;
/// Workgroups per dispatch dimension guaranteed by downlevel limits.
pub(crate) const MAX_GROUPS: u32 = 65535;

/// The buffer kept in `slot` when it has at least `bytes`, else a new one of the next power of
/// two bytes with `usage`, kept there in its place (commands already recorded keep the old one
/// alive). Passes that share such a buffer run in the order they were recorded, and wgpu orders
/// each pass's accesses after the previous pass's, so a later pass cannot overwrite what an
/// earlier one has yet to read.
pub(crate) fn kept_buffer(
    slot: &Mutex<Option<wgpu::Buffer>>,
    device: &wgpu::Device,
    bytes: u64,
    usage: wgpu::BufferUsages,
    label: &str,
) -> wgpu::Buffer {
    let mut slot = slot.lock().unwrap_or_else(|e| e.into_inner());
    match &*slot {
        Some(buffer) if buffer.size() >= bytes => buffer.clone(),
        _ => {
            let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes.next_power_of_two(),
                usage,
                mapped_at_creation: false,
            });
            *slot = Some(buffer.clone());
            buffer
        }
    }
}

/// Checks that `out` can take `bytes` from byte `offset` (the last word whole); returns the
/// offset in words.
pub(crate) fn check_output(
    device: &wgpu::Device,
    out: &wgpu::Buffer,
    offset: u64,
    bytes: u64,
) -> Result<u32, GpuError> {
    if !out.usage().contains(wgpu::BufferUsages::STORAGE) {
        return Err(GpuError::OutputBuffer { reason: "it needs STORAGE usage" });
    }
    if !offset.is_multiple_of(4) {
        return Err(GpuError::OutputBuffer { reason: "the offset is not a multiple of 4" });
    }
    if out.size() > device.limits().max_storage_buffer_binding_size {
        return Err(GpuError::OutputBuffer {
            reason: "it is larger than the device's storage binding limit",
        });
    }
    let needed = offset + bytes.next_multiple_of(4);
    if needed > out.size() {
        return Err(GpuError::Output { needed, size: out.size() });
    }
    u32::try_from(offset / 4)
        .map_err(|_| GpuError::OutputBuffer { reason: "the offset is 2^34 bytes or more" })
}

/// Checks that `requests` holds `bytes` of requests from byte `offset` and can be bound;
/// returns the offset in words.
pub(crate) fn check_requests(
    device: &wgpu::Device,
    requests: &wgpu::Buffer,
    offset: u64,
    bytes: u64,
) -> Result<u32, GpuError> {
    let reason = if !requests.usage().contains(wgpu::BufferUsages::STORAGE) {
        Some("it needs STORAGE usage")
    } else if !offset.is_multiple_of(4) {
        Some("the offset is not a multiple of 4")
    } else if requests.size() > device.limits().max_storage_buffer_binding_size {
        Some("it is larger than the device's storage binding limit")
    } else if offset + bytes > requests.size() {
        Some("it ends before the last request")
    } else {
        None
    };
    if let Some(reason) = reason {
        return Err(GpuError::RequestBuffer { reason });
    }
    u32::try_from(offset / 4)
        .map_err(|_| GpuError::RequestBuffer { reason: "the offset is 2^34 bytes or more" })
}

/// A compute-stage storage buffer binding of a bind group layout.
pub(crate) fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A compute-stage uniform buffer binding of a bind group layout.
pub(crate) fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// The bytes of `source` (a `COPY_SRC` buffer): copied into a mappable buffer, submitted, mapped
/// (blocks on the device). For tests and tools; a renderer keeps its results on the GPU.
pub fn read_buffer(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    source: &wgpu::Buffer,
) -> Result<Vec<u8>, GpuError> {
    read_back(device, &copy_for_reading(device, queue, source), source.size())
}

/// [`read_buffer`] without blocking (e.g. on WebGPU in a browser): the copy is submitted now;
/// the future is ready once the device has run it and been polled (the browser's event loop,
/// or natively the caller's `Device::poll`). For tests and tools.
pub async fn read_buffer_async(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    source: &wgpu::Buffer,
) -> Result<Vec<u8>, GpuError> {
    read_back_async(&copy_for_reading(device, queue, source), source.size()).await
}

/// A mappable copy of `source` (a `COPY_SRC` buffer), submitted.
fn copy_for_reading(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    source: &wgpu::Buffer,
) -> wgpu::Buffer {
    let back = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("nmat readback"),
        size: source.size(),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(source, 0, &back, 0, source.size());
    queue.submit([encoder.finish()]);
    back
}

/// [`read_buffer`], waiting at most `timeout` for the device (`None` where it had not finished).
pub(crate) fn read_buffer_within(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    source: &wgpu::Buffer,
    timeout: std::time::Duration,
) -> Result<Option<Vec<u8>>, GpuError> {
    let back = copy_for_reading(device, queue, source);
    read_back_within(device, &back, source.size(), (None, Some(timeout)))
}

/// Maps the first `bytes` of `buffer` (blocking on the device) and returns them.
pub(crate) fn read_back(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<u8>, GpuError> {
    read_back_after(device, buffer, bytes, None)
}

/// [`read_back`] once the queue has run `submission` (the one that writes `buffer`; `None`:
/// everything submitted so far), not waiting for work submitted after it.
pub(crate) fn read_back_after(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
    bytes: u64,
    submission: Option<wgpu::SubmissionIndex>,
) -> Result<Vec<u8>, GpuError> {
    read_back_within(device, buffer, bytes, (submission, None))?
        .ok_or_else(|| GpuError::Map("the wait ended before the device".into()))
}

/// How a call gets the device's answers (a probe's codes, a shader's validation): by blocking
/// until they come (the synchronous calls, which a browser refuses), or by awaiting them (the
/// `_async` calls, which never block: the answers come when the device is polled, by the
/// browser's event loop or the caller's `Device::poll`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Waits {
    Block,
    Await,
}

/// `future` polled once (with a waker that does nothing): its output where it is ready at once,
/// else `None` (the future is dropped). The synchronous calls run their `async` logic through it:
/// with [`Waits::Block`] every answer they await is ready when asked for.
pub(crate) fn now<F: Future>(future: F) -> Option<F::Output> {
    let mut future = std::pin::pin!(future);
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    match future.as_mut().poll(&mut cx) {
        std::task::Poll::Ready(output) => Some(output),
        std::task::Poll::Pending => None,
    }
}

/// What a mapping's callback left: its outcome once it ran, and the waker of the task awaiting it.
#[derive(Default)]
struct MapState {
    outcome: Option<Result<(), wgpu::BufferAsyncError>>,
    waker: Option<std::task::Waker>,
}

/// The outcome of a `map_async`, awaited: ready once its callback has run (in a poll of the
/// device: the browser's event loop, or the caller's `Device::poll` natively).
struct Mapping(std::sync::Arc<Mutex<MapState>>);

impl Future for Mapping {
    type Output = Result<(), wgpu::BufferAsyncError>;

    fn poll(
        self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Self::Output> {
        let mut state = self.0.lock().unwrap_or_else(|e| e.into_inner());
        match state.outcome.take() {
            Some(outcome) => std::task::Poll::Ready(outcome),
            None => {
                state.waker = Some(cx.waker().clone());
                std::task::Poll::Pending
            }
        }
    }
}

/// The first `bytes` of `buffer` (a `MAP_READ` buffer that submitted work writes), mapped
/// without blocking: the future is ready once the device has run that work and been polled.
/// Dropping it before then leaves the buffer mapping (not to be reused).
pub(crate) async fn read_back_async(
    buffer: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<u8>, GpuError> {
    let state = std::sync::Arc::new(Mutex::new(MapState::default()));
    let callback_state = std::sync::Arc::clone(&state);
    buffer.map_async(wgpu::MapMode::Read, ..bytes, move |outcome| {
        let mut state = callback_state.lock().unwrap_or_else(|e| e.into_inner());
        state.outcome = Some(outcome);
        if let Some(waker) = state.waker.take() {
            waker.wake();
        }
    });
    Mapping(state).await.map_err(|e| GpuError::Map(e.to_string()))?;
    mapped_bytes(buffer, bytes)
}

/// The first `bytes` of `buffer`, mapped for reading: copied out, then the buffer unmapped.
fn mapped_bytes(buffer: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, GpuError> {
    let view = buffer.get_mapped_range(..bytes).map_err(|e| GpuError::Map(e.to_string()))?;
    let out = view.to_vec();
    drop(view);
    buffer.unmap();
    Ok(out)
}

/// Whether the calls that wait for the device can on `backend`: on every backend but WebGPU in a
/// browser, whose polls return at once and whose mappings complete only in the browser's event
/// loop (a wait there would never end).
pub(crate) fn waits_on(backend: wgpu::Backend) -> bool {
    backend != wgpu::Backend::BrowserWebGpu
}

/// [`GpuError::CannotWait`] where `device` cannot be waited on ([`waits_on`]); every call that
/// waits for the device asks this first. Only a WebAssembly build has the browser's backend:
/// elsewhere there is nothing to ask (and no `AdapterInfo` to copy on every wait).
pub(crate) fn check_can_wait(device: &wgpu::Device) -> Result<(), GpuError> {
    let browser = cfg!(target_arch = "wasm32") && !waits_on(device.adapter_info().backend);
    if browser || REFUSE_WAITS.get() {
        return Err(GpuError::CannotWait);
    }
    Ok(())
}

std::thread_local! {
    /// Whether the calls that wait for the device refuse to on this thread, as in a browser
    /// ([`refuse_waits_on_this_thread_for_testing`]).
    static REFUSE_WAITS: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Makes every call that waits for the device return [`GpuError::CannotWait`] on the calling
/// thread (`true`), as on WebGPU in a browser, or wait again (`false`): so that a native test
/// can see that the asynchronous calls never block. For tests only.
#[doc(hidden)]
pub fn refuse_waits_on_this_thread_for_testing(refuse: bool) {
    REFUSE_WAITS.set(refuse);
}

/// Whether the queue has run `submission`, waiting at most `timeout` for it (zero: asks without
/// blocking).
pub(crate) fn finished_within(
    device: &wgpu::Device,
    submission: &wgpu::SubmissionIndex,
    timeout: std::time::Duration,
) -> Result<bool, GpuError> {
    check_can_wait(device)?;
    let wait =
        wgpu::PollType::Wait { submission_index: Some(submission.clone()), timeout: Some(timeout) };
    match device.poll(wait) {
        Ok(status) => Ok(status.wait_finished()),
        Err(wgpu::PollError::Timeout) => Ok(false),
        Err(e) => Err(GpuError::Map(e.to_string())),
    }
}

/// [`read_back_after`] `submission`, waiting at most `timeout` for the device: `None` where it
/// had not finished (the buffer is then left mapping, not to be reused).
pub(crate) fn read_back_within(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
    bytes: u64,
    (submission, timeout): (Option<wgpu::SubmissionIndex>, Option<std::time::Duration>),
) -> Result<Option<Vec<u8>>, GpuError> {
    check_can_wait(device)?;
    let (tx, rx) = mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, ..bytes, move |r| {
        let _ = tx.send(r);
    });
    match device.poll(wgpu::PollType::Wait { submission_index: submission, timeout }) {
        Err(wgpu::PollError::Timeout) => return Ok(None),
        other => other.map_err(|e| GpuError::Map(e.to_string()))?,
    };
    rx.recv()
        .map_err(|e| GpuError::Map(e.to_string()))?
        .map_err(|e| GpuError::Map(e.to_string()))?;
    mapped_bytes(buffer, bytes).map(Some)
}

/// The compute pipeline of `entry` in `source` (with `layout`, or the one wgpu derives), or
/// `None` where the device refuses it (a shader language feature it lacks, a limit), as the
/// device answers now ([`checked_pipeline`] with [`Waits::Block`]).
pub(crate) fn try_pipeline(
    device: &wgpu::Device,
    source: &str,
    entry: &str,
    layout_and_cache: (Option<&wgpu::PipelineLayout>, Option<&wgpu::PipelineCache>),
) -> Option<wgpu::ComputePipeline> {
    now(checked_pipeline(device, source, entry, layout_and_cache, Waits::Block)).flatten()
}

/// The compute pipeline of `entry` in `source`, created (and its error scopes popped) when this
/// is called, once the device has said whether it took the shader: `None` where it refused it.
/// wgpu's native backends answer at once. WebGPU in a browser answers later: with
/// [`Waits::Await`] the future waits for that answer (an optional pipeline, such as a faster
/// kernel, is used only once it is known good); with [`Waits::Block`] it is ready at once and
/// an answer still pending takes the pipeline (one nmat cannot do without; were it invalid, a
/// pass that used it would be a validation error, reported by the device as any wgpu call's).
pub(crate) fn checked_pipeline(
    device: &wgpu::Device,
    source: &str,
    entry: &str,
    (layout, cache): (Option<&wgpu::PipelineLayout>, Option<&wgpu::PipelineCache>),
    waits: Waits,
) -> impl Future<Output = Option<wgpu::ComputePipeline>> + use<> {
    let internal = device.push_error_scope(wgpu::ErrorFilter::Internal);
    let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(entry),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout,
        module: &module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache,
    });
    // Popped now, innermost first; their answers taken below.
    let (validation, internal) = (validation.pop(), internal.pop());
    async move {
        let refused = match waits {
            Waits::Await => validation.await.is_some() | internal.await.is_some(),
            Waits::Block => {
                matches!(now(validation), Some(Some(_))) | matches!(now(internal), Some(Some(_)))
            }
        };
        (!refused).then_some(pipeline)
    }
}

/// A bind group of the decode kernels' layout (context.rs) and the dispatch's parameters where
/// they are not in it: set as immediates (a device with them) before the dispatch; and the
/// material's matrix weights (group 1) where its kernel reads them from storage.
#[derive(Clone)]
pub(crate) struct Bound {
    pub group: wgpu::BindGroup,
    pub immediates: Option<Vec<u8>>,
    pub weights: Option<wgpu::BindGroup>,
}

impl Bound {
    /// `group` with its parameters as `immediates` where given (no weights group).
    pub fn new(group: wgpu::BindGroup, immediates: Option<Vec<u8>>) -> Bound {
        Bound { group, immediates, weights: None }
    }

    /// This binding with `gm`'s matrix weights group, where its kernel has one, for a dispatch
    /// of its kernel (or its tile entry).
    pub fn with_weights_of(self, gm: &crate::GpuMaterial) -> Bound {
        Bound { weights: gm.weights.clone(), ..self }
    }

    /// Sets the groups and immediates on `pass`.
    pub fn set(&self, pass: &mut wgpu::ComputePass<'_>) {
        pass.set_bind_group(0, &self.group, &[]);
        if let Some(weights) = &self.weights {
            pass.set_bind_group(crate::matrix::WEIGHTS_GROUP, weights, &[]);
        }
        if let Some(bytes) = &self.immediates {
            pass.set_immediates(0, bytes);
        }
    }
}

/// Records one dispatch of `groups` workgroups (spread over x and y past the per-dimension limit).
pub(crate) fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    bind: &wgpu::BindGroup,
    groups: u64,
) {
    let bound = Bound::new(bind.clone(), None);
    dispatch_bound(encoder, pipeline, &bound, groups);
}

/// [`dispatch`] with a [`Bound`]: its immediates set first where it has them.
pub(crate) fn dispatch_bound(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    bound: &Bound,
    groups: u64,
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some("nmat"),
        timestamp_writes: None,
    });
    pass.set_pipeline(pipeline);
    bound.set(&mut pass);
    if groups > 0 {
        let (gx, gy) = spread(groups);
        pass.dispatch_workgroups(gx, gy, 1);
    }
}

/// `groups` workgroups as a dispatch's x and y (at least 1 each): x up to the per-dimension
/// limit, y rows of it; shaders index workgroup x + y · (x count).
pub(crate) fn spread(groups: u64) -> (u32, u32) {
    let gx = groups.min(u64::from(MAX_GROUPS)) as u32;
    let gy = groups.div_ceil(u64::from(MAX_GROUPS)) as u32;
    (gx.max(1), gy.max(1))
}

/// A uniform buffer holding `bytes` (a dispatch's parameters).
pub(crate) fn uniform_buffer(device: &wgpu::Device, bytes: &[u8]) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("nmat params"),
        contents: bytes,
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

/// Bind groups kept for the last few distinct keys (the buffers, and what else a call binds),
/// most recent first, so that a call repeating a recent one's key allocates nothing. The kept
/// groups hold references to what they bind until later keys push them out or they are dropped.
pub(crate) struct KeptBinds<K> {
    kept: std::sync::Mutex<Vec<(K, wgpu::BindGroup)>>,
    capacity: usize,
}

impl<K: PartialEq> KeptBinds<K> {
    pub fn new(capacity: usize) -> KeptBinds<K> {
        KeptBinds { kept: std::sync::Mutex::default(), capacity }
    }

    /// The group kept for `key` (now the most recent), else the one `make` makes for it, kept
    /// (the oldest dropped past the capacity).
    pub fn get_or_make(&self, key: K, make: impl FnOnce(&K) -> wgpu::BindGroup) -> wgpu::BindGroup {
        let mut kept = self.kept.lock().unwrap_or_else(|e| e.into_inner());
        let entry = match kept.iter().position(|(k, _)| *k == key) {
            Some(at) => kept.remove(at),
            None => {
                let group = make(&key);
                (key, group)
            }
        };
        let group = entry.1.clone();
        kept.insert(0, entry);
        kept.truncate(self.capacity);
        group
    }

    /// Drops the kept groups whose key `drop` names.
    pub fn forget(&self, drop: impl Fn(&K) -> bool) {
        self.kept.lock().unwrap_or_else(|e| e.into_inner()).retain(|(k, _)| !drop(k));
    }
}

#[cfg(test)]
mod tests {
    use wgpu::Backend;

    /// Waits are refused on WebGPU in a browser only (wgpu 30's WebGPU backend answers every
    /// poll at once, and a mapping's callback runs in the browser's event loop); the native
    /// backends and the no-op one wait. Every backend wgpu has is named here, so a new one
    /// fails the test until it is decided.
    #[test]
    fn only_a_browser_cannot_be_waited_on() {
        let native = [Backend::Noop, Backend::Vulkan, Backend::Metal, Backend::Dx12, Backend::Gl];
        for backend in Backend::ALL {
            let expected = native.contains(&backend);
            assert!(expected || backend == Backend::BrowserWebGpu, "{backend:?} is not decided");
            assert_eq!(super::waits_on(backend), expected, "{backend:?}");
        }
    }
}
