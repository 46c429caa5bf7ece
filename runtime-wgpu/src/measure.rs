//! Measuring the GPU like a GPU (docs/GPU.md, "Measured"): recorded work timed between GPU
//! timestamps where the device has them, and the adapter's peak rates of 32-bit integer
//! multiply-adds and `dot4I8Packed` from register-only WGSL loops (`probe.wgsl`), the roofline
//! the decoder is compared against.

use crate::GpuError;
use crate::gpu::{dispatch, read_back, try_pipeline};
use crate::layout::words_to_bytes;
use std::time::Instant;
use wgpu::util::DeviceExt;

/// Which part of a tiled or matrix kernel's work a pipeline does: all of it, or — to time where
/// a kernel's time goes, its codes then not the material's — only the input features (every
/// texel's latents, positional encoding and LOD, staged for the layers, then folded into its
/// codes so that no compiler drops them as never read) or only the layers (on cheap stand-in
/// features that vary by texel). [`crate::Context::upload_part_for_timing`] builds
/// such a material; `nmat bench --gpu` prints a row for each part of each such kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Part {
    Whole,
    Features,
    Layers,
}

impl Part {
    /// `const PART` of a tiled or matrix kernel's source: 0 whole, 1 the features alone, 2 the
    /// layers alone.
    pub(crate) fn code(self) -> u32 {
        match self {
            Part::Whole => 0,
            Part::Features => 1,
            Part::Layers => 2,
        }
    }

    /// What a part pipeline's source adds (tiled.wgsl and matrix.wgsl call it where
    /// `PART == 2u`): stand-in input features for timing the layers alone, cheap, varying by
    /// texel and row (so that no compiler folds the layers over constants), in i16's range.
    pub(crate) const STAND_IN_WGSL: &'static str = "\
fn stand_in_features(index: u32, inputs: u32) {
    for (var k = 0u; k < inputs; k++) {
        nmat_act_a[k] = i32(((index + 1u) * 0x9E3779B1u + k * 0x85EBCA77u) >> 18u) - 8192;
    }
}
";

    pub fn name(self) -> &'static str {
        match self {
            Part::Whole => "whole",
            Part::Features => "input features only",
            Part::Layers => "layers only",
        }
    }
}

/// How a time was taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Clock {
    /// Between two GPU timestamps around the work (`TIMESTAMP_QUERY` and
    /// `TIMESTAMP_QUERY_INSIDE_ENCODERS`): the kernels alone.
    Timestamps,
    /// From submit to completion on the CPU's clock: includes the submission.
    WallClock,
}

impl Clock {
    pub fn name(self) -> &'static str {
        match self {
            Clock::Timestamps => "GPU timestamps",
            Clock::WallClock => "wall clock (no timestamp queries)",
        }
    }
}

/// The features [`time_recorded`] times with; request them (where the adapter has them) when
/// creating a device for measuring. [`crate::default_device`] does.
pub const TIMESTAMP_FEATURES: wgpu::Features =
    wgpu::Features::TIMESTAMP_QUERY.union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS);

/// Seconds per repeat of the work `record` adds to a command encoder, recorded `repeats` times
/// into one submission (after one untimed warm-up submission of a single repeat).
pub fn time_recorded(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    repeats: u32,
    mut record: impl FnMut(&mut wgpu::CommandEncoder) -> Result<(), GpuError>,
) -> Result<(f64, Clock), GpuError> {
    crate::gpu::check_can_wait(device)?;
    let repeats = repeats.max(1);
    let mut warm = device.create_command_encoder(&Default::default());
    record(&mut warm)?;
    queue.submit([warm.finish()]);
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Map(e.to_string()))?;
    let (seconds, clock) = time_once(device, queue, |encoder| {
        for _ in 0..repeats {
            record(encoder)?;
        }
        Ok(())
    })?;
    Ok((seconds / f64::from(repeats), clock))
}

/// Seconds of the work `record` adds to one command encoder, submitted once (no warm-up: for
/// work that changes state, such as a tile cache's frame): between GPU timestamps where the
/// device has them ([`TIMESTAMP_FEATURES`]), else from submit to completion.
pub fn time_once(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    record: impl FnOnce(&mut wgpu::CommandEncoder) -> Result<(), GpuError>,
) -> Result<(f64, Clock), GpuError> {
    let mut record = Some(record);
    let mut stage = |encoder: &mut wgpu::CommandEncoder| match record.take() {
        Some(record) => record(encoder),
        None => Ok(()),
    };
    let timed = time_stages(device, queue, &mut [&mut stage])?;
    Ok((timed.seconds, timed.clock))
}

/// A stage of [`time_stages`]: it records its work into the encoder.
pub type Stage<'a> = &'a mut dyn FnMut(&mut wgpu::CommandEncoder) -> Result<(), GpuError>;

/// What [`time_stages`] measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Stages {
    /// The whole submission's work.
    pub seconds: f64,
    /// Each stage's seconds, between GPU timestamps written after the stage before it (their
    /// sum is `seconds`); `None` on the wall clock, which times only the whole.
    pub stages: Option<Vec<f64>>,
    pub clock: Clock,
}

/// Seconds of each of `stages` (each records its work into the same command encoder, in order),
/// submitted once as [`time_once`]: a GPU timestamp before the first stage and after each, so
/// a frame's passes (a tile cache's mark, decode, resolve) are timed apart in one submission.
pub fn time_stages(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    stages: &mut [Stage<'_>],
) -> Result<Stages, GpuError> {
    crate::gpu::check_can_wait(device)?;
    let wait = |device: &wgpu::Device| {
        device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Map(e.to_string()))
    };
    let timestamps = device.features().contains(TIMESTAMP_FEATURES);
    let mut encoder = device.create_command_encoder(&Default::default());
    let count = stages.len() as u32 + 1;
    let queries = timestamps.then(|| {
        device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("nmat timing"),
            ty: wgpu::QueryType::Timestamp,
            count,
        })
    });
    if let Some(q) = &queries {
        encoder.write_timestamp(q, 0);
    }
    for (k, stage) in stages.iter_mut().enumerate() {
        stage(&mut encoder)?;
        if let Some(q) = &queries {
            encoder.write_timestamp(q, k as u32 + 1);
        }
    }
    let Some(q) = &queries else {
        let start = Instant::now();
        queue.submit([encoder.finish()]);
        wait(device)?;
        let seconds = start.elapsed().as_secs_f64();
        return Ok(Stages { seconds, stages: None, clock: Clock::WallClock });
    };
    let bytes = 8 * u64::from(count);
    let resolve = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("nmat timestamps"),
        size: bytes,
        usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let back = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("nmat timestamps readback"),
        size: bytes,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    encoder.resolve_query_set(q, 0..count, &resolve, 0);
    encoder.copy_buffer_to_buffer(&resolve, 0, &back, 0, bytes);
    queue.submit([encoder.finish()]);
    let ticks: Vec<u64> = read_back(device, &back, bytes)?
        .chunks_exact(8)
        .map(|b| u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
        .collect();
    let period = f64::from(queue.get_timestamp_period()) * 1e-9;
    let seconds = |from: usize, to: usize| ticks[to].saturating_sub(ticks[from]) as f64 * period;
    let each = (1..ticks.len()).map(|k| seconds(k - 1, k)).collect();
    Ok(Stages {
        seconds: seconds(0, ticks.len() - 1),
        stages: Some(each),
        clock: Clock::Timestamps,
    })
}

/// The adapter's peak rates, measured by [`probe_peak`].
#[derive(Clone, Copy, Debug)]
pub struct Peak {
    /// 32-bit integer multiply-adds per second (`a = a * m + c`).
    pub i32_mad_per_s: f64,
    /// 8-bit multiply-accumulates per second through `dot4I8Packed` (4 per call), or `None`
    /// where the shader language lacks it.
    pub dot4_mac_per_s: Option<f64>,
    pub clock: Clock,
}

/// Invocations of one probe dispatch: enough to fill any current GPU.
const PROBE_GROUPS: u32 = 4096;
/// Operations per iteration of a probe loop: 4 rounds × 8 chains.
const PROBE_OPS: f64 = 32.0;

/// Measures [`Peak`] on `device`: each probe grows its loop until one dispatch takes at least
/// 20 ms, then reports the best of three.
pub fn probe_peak(device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Peak, GpuError> {
    let probe = include_str!("shaders/probe.wgsl");
    let mad = try_pipeline(device, probe, "mad", (None, None)).ok_or(GpuError::Map(
        "the integer peak probe did not compile on this device".to_string(),
    ))?;
    let (mad_rate, clock) = rate(device, queue, &mad, 1.0)?;
    let dot4_source = format!("{probe}\n{}", include_str!("shaders/probe_dot4.wgsl"));
    let dot4 = try_pipeline(device, &dot4_source, "dot4", (None, None));
    let dot4_mac_per_s = match dot4 {
        Some(p) => Some(rate(device, queue, &p, 4.0)?.0),
        None => None,
    };
    Ok(Peak { i32_mad_per_s: mad_rate, dot4_mac_per_s, clock })
}

/// Operations per second of a probe pipeline doing `per_op` units per operation.
fn rate(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    pipeline: &wgpu::ComputePipeline,
    per_op: f64,
) -> Result<(f64, Clock), GpuError> {
    let invocations = u64::from(PROBE_GROUPS) * 64;
    let sink = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("nmat probe sink"),
        size: invocations * 4,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    let run = |iterations: u32| -> Result<(f64, Clock), GpuError> {
        let words = [iterations, 0x0101_0103, 0x2545_F491, 0];
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("nmat probe"),
            contents: &words_to_bytes(&words),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("nmat probe"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: sink.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: uniform.as_entire_binding() },
            ],
        });
        time_recorded(device, queue, 1, |encoder| {
            dispatch(encoder, pipeline, &bind, u64::from(PROBE_GROUPS));
            Ok(())
        })
    };
    let mut iterations = 16u32;
    let (mut seconds, mut clock) = run(iterations)?;
    while seconds < 0.02 && iterations < 1 << 20 {
        iterations *= 4;
        (seconds, clock) = run(iterations)?;
    }
    for _ in 0..2 {
        seconds = seconds.min(run(iterations)?.0);
    }
    let ops = invocations as f64 * f64::from(iterations) * PROBE_OPS * per_op;
    Ok((ops / seconds.max(1e-12), clock))
}
