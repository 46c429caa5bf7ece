//! Submit-then-map decodes: the buffers they reuse (a pool per [`Context`]) and the
//! [`PendingDecode`] that maps the result.

use crate::gpu::{Bound, dispatch_bound, finished_within, read_back_after, read_back_async};
use crate::layout::{Params, ShaderLayout};
use crate::upload::GpuBody;
use crate::{Context, GpuError, GpuMaterial};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Work submitted to the queue; `wait` maps the result: `channels` 8-bit codes per texel, in
/// request (or row-major) order.
pub struct PendingDecode {
    /// `scratch`'s output and readback buffers (handles to the same buffers).
    out: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// Given back to `pool` on `wait` or drop.
    scratch: Option<Scratch>,
    pool: Pool,
    len: usize,
    /// The submission that writes the result.
    submission: wgpu::SubmissionIndex,
}

pub(crate) type Pool = Arc<Mutex<Vec<Scratch>>>;

impl Context {
    /// Takes reusable buffers with room for `out_bytes` of codes and `request_bytes` of
    /// requests from the pool, or makes new ones.
    pub(crate) fn take_scratch(
        &self,
        device: &wgpu::Device,
        out_bytes: u64,
        request_bytes: u64,
    ) -> Scratch {
        let mut pool = self.pool.lock().unwrap_or_else(|e| e.into_inner());
        let fits = |s: &Scratch| s.out.size() >= out_bytes && s.requests.size() >= request_bytes;
        if let Some(k) = pool.iter().position(fits) {
            return pool.swap_remove(k);
        }
        drop(pool);
        Scratch::new(device, out_bytes, request_bytes)
    }

    /// Submits a decode with the pool's buffers (bind group reused when the material is the
    /// one they were last bound to).
    pub(crate) fn submit(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        params: Params,
        requests: &[u8],
    ) -> Result<PendingDecode, GpuError> {
        // A JPEG material records its own passes (no uniform or bind group to reuse).
        let neural = match &gm.body {
            GpuBody::Neural(tiled) => Ok((tiled, self.decode_groups(device, tiled, &params)?)),
            GpuBody::Jpeg(maps) => Err(maps),
        };
        let len = u64::from(params.count) * u64::from(params.out_channels);
        let copy = len.next_multiple_of(4).max(4);
        let mut scratch = self.take_scratch(device, copy, requests.len() as u64);
        if !requests.is_empty() {
            queue.write_buffer(&scratch.requests, 0, requests);
        }
        let mut encoder = device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("nmat decode") });
        let (tiled, groups) = match neural {
            Ok(neural) => neural,
            Err(maps) => {
                let requests = Some(&scratch.requests);
                self.record_jpeg(device, &mut encoder, (gm, maps), params, requests, &scratch.out)?;
                return Ok(self.finish(queue, encoder, scratch, len));
            }
        };
        // The parameters as immediates, or written into the set's uniform.
        let bytes = params.bytes();
        if !self.immediates {
            queue.write_buffer(&scratch.uniform, 0, &bytes);
        }
        if scratch.bind.as_ref().is_none_or(|(id, _)| *id != gm.id) {
            let buffers = [&gm.desc, &gm.latents, &scratch.requests, &scratch.out];
            let uniform = (!self.immediates).then_some(&scratch.uniform);
            scratch.bind = Some((gm.id, self.make_group(device, buffers, uniform)));
        }
        if let Some((_, group)) = &scratch.bind {
            let immediates = self.immediates.then_some(bytes);
            let bound = Bound::new(group.clone(), immediates).with_weights_of(gm);
            dispatch_bound(&mut encoder, self.decode_pipeline(tiled).0, &bound, groups);
        }
        Ok(self.finish(queue, encoder, scratch, len))
    }

    /// Copies the codes of `scratch` to its readback buffer after the work in `encoder`, submits,
    /// and hands the buffers to the [`PendingDecode`] (`len` codes).
    pub(crate) fn finish(
        &self,
        queue: &wgpu::Queue,
        mut encoder: wgpu::CommandEncoder,
        scratch: Scratch,
        len: u64,
    ) -> PendingDecode {
        let copy = len.next_multiple_of(4).max(4);
        encoder.copy_buffer_to_buffer(&scratch.out, 0, &scratch.readback, 0, copy);
        let submission = queue.submit([encoder.finish()]);
        PendingDecode {
            out: scratch.out.clone(),
            readback: scratch.readback.clone(),
            scratch: Some(scratch),
            pool: Arc::clone(&self.pool),
            len: len as usize,
            submission,
        }
    }
}

impl PendingDecode {
    /// The GPU-side result: the codes packed four per `u32` (the buffer's bytes from 0 are the
    /// codes in order, channels fastest), usable as a storage buffer by the caller's own passes
    /// without a round trip through the CPU. The buffer may be longer than the result; it is
    /// reused by later decodes once this one is waited on or dropped.
    pub fn gpu_buffer(&self) -> &wgpu::Buffer {
        &self.out
    }

    /// Number of codes in the result.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Maps the result (blocking until the device has run its submission, not the work
    /// submitted after it) and returns the codes.
    pub fn wait(mut self, device: &wgpu::Device) -> Result<Vec<u8>, GpuError> {
        let bytes = (self.len as u64).next_multiple_of(4).max(4);
        let submission = Some(self.submission.clone());
        let mut bytes = read_back_after(device, &self.readback, bytes, submission)?;
        bytes.truncate(self.len);
        self.give_back();
        Ok(bytes)
    }

    /// [`PendingDecode::wait`] without blocking, e.g. on WebGPU in a browser (where `wait`
    /// returns [`GpuError::CannotWait`]): the future is ready with the codes once the device has
    /// run the decode and been polled — by the browser's event loop, or natively by the
    /// caller's `Device::poll` (`PollType::Poll` once a frame never blocks). Dropped before then,
    /// its buffers are not reused.
    pub async fn wait_async(mut self) -> Result<Vec<u8>, GpuError> {
        // Kept out of the pool until the codes are mapped: a future dropped while its buffer
        // is mapping must not hand that buffer to another decode.
        let scratch = self.scratch.take();
        let bytes = (self.len as u64).next_multiple_of(4).max(4);
        let mut codes = read_back_async(&self.readback, bytes).await?;
        codes.truncate(self.len);
        self.scratch = scratch;
        self.give_back();
        Ok(codes)
    }

    /// Whether the device has run this decode, waiting at most `wait` for it: with
    /// `Duration::ZERO` it asks without blocking (e.g. once a frame, for a decode kept in flight
    /// across frames). Once it says `true`, [`PendingDecode::wait`] maps the codes without
    /// waiting for the device; `false` leaves the decode as it was, to be asked again, waited on
    /// or dropped. [`GpuError::CannotWait`] on WebGPU in a browser, where nothing can wait for
    /// the device (its polls do not).
    pub fn is_finished(&self, device: &wgpu::Device, wait: Duration) -> Result<bool, GpuError> {
        finished_within(device, &self.submission, wait)
    }

    /// [`PendingDecode::wait`], waiting at most `timeout` for the device: `None` where it had
    /// not finished (its buffers, possibly still being written by a kernel that does not end,
    /// are then not reused).
    pub(crate) fn wait_within(
        mut self,
        device: &wgpu::Device,
        timeout: Duration,
    ) -> Result<Option<Vec<u8>>, GpuError> {
        if self.is_finished(device, timeout)? {
            return self.wait(device).map(Some);
        }
        self.scratch = None;
        Ok(None)
    }

    /// Returns the buffers to the context's pool (at most [`POOL`] are kept).
    fn give_back(&mut self) {
        if let Some(scratch) = self.scratch.take() {
            let mut pool = self.pool.lock().unwrap_or_else(|e| e.into_inner());
            if pool.len() < POOL {
                pool.push(scratch);
            }
        }
    }
}

impl Drop for PendingDecode {
    fn drop(&mut self) {
        self.give_back();
    }
}

/// Buffers of the submit-and-wait calls, reused between calls: a submit takes a set from the
/// context's pool (or makes one) and its [`PendingDecode`] gives it back.
pub(crate) struct Scratch {
    uniform: wgpu::Buffer,
    requests: wgpu::Buffer,
    out: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// The bind group of these buffers with the material of this id ([`GpuMaterial`]).
    bind: Option<(u64, wgpu::BindGroup)>,
}

/// Most sets of buffers a context keeps for reuse.
const POOL: usize = 8;

impl Scratch {
    /// Room for `out_bytes` of codes and `request_bytes` of requests, rounded up to a power of
    /// two (so that nearby sizes reuse the set) where the binding limit allows.
    fn new(device: &wgpu::Device, out_bytes: u64, request_bytes: u64) -> Scratch {
        let max_binding = device.limits().max_storage_buffer_binding_size;
        let room = |n: u64| {
            let n = n.next_multiple_of(4).max(16);
            if n.next_power_of_two() <= max_binding { n.next_power_of_two() } else { n }
        };
        let buffer = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let out_size = room(out_bytes);
        Scratch {
            uniform: buffer("nmat params", size_of::<Params>() as u64, U::UNIFORM | U::COPY_DST),
            requests: buffer("nmat requests", room(request_bytes), U::STORAGE | U::COPY_DST),
            out: buffer("nmat codes", out_size, U::STORAGE | U::COPY_SRC),
            readback: buffer("nmat readback", out_size, U::MAP_READ | U::COPY_DST),
            bind: None,
        }
    }
}
