//! What the GPU tests share: the device, and a small trained material.

/// The first adapter wgpu finds (lavapipe in CI); none is a failure, not a skip.
pub fn device() -> (wgpu::Device, wgpu::Queue) {
    let (device, queue, info) = pollster::block_on(nmat_wgpu::default_device()).expect(
        "no GPU adapter found: install a Vulkan driver (CI: apt-get install mesa-vulkan-drivers libvulkan1)",
    );
    eprintln!("adapter: {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    (device, queue)
}

/// The bytes of the demo bricks (64²) trained for 150 steps.
#[allow(dead_code)] // not every test file uses every helper
pub fn trained_material() -> Vec<u8> {
    let set = nmat_encode::demo::bricks(64);
    let options = nmat_encode::EncodeOptions {
        train: nmat_encode::TrainOptions { steps: 150, ..Default::default() },
        ..Default::default()
    };
    nmat_encode::encode(&set, &options, &mut |_| {}).unwrap().bytes
}

/// A buffer of `size` bytes; with `fill`, its bytes are set to that value first.
#[allow(dead_code)] // not every test file uses every helper
pub fn buffer(
    device: &wgpu::Device,
    size: u64,
    usage: wgpu::BufferUsages,
    fill: Option<u8>,
) -> wgpu::Buffer {
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size,
        usage,
        mapped_at_creation: fill.is_some(),
    });
    if let Some(v) = fill {
        buffer.get_mapped_range_mut(..).unwrap().copy_from_slice(&vec![v; size as usize]);
        buffer.unmap();
    }
    buffer
}

/// The bytes of `source` (`COPY_SRC`), copied into a mappable buffer after the work in
/// `encoder`, which this submits.
#[allow(dead_code)]
pub fn submit_and_read(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    mut encoder: wgpu::CommandEncoder,
    source: &wgpu::Buffer,
) -> Vec<u8> {
    let size = source.size();
    let back =
        buffer(device, size, wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST, None);
    encoder.copy_buffer_to_buffer(source, 0, &back, 0, size);
    queue.submit([encoder.finish()]);
    back.map_async(wgpu::MapMode::Read, .., |r| r.unwrap());
    device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
    back.get_mapped_range(..).unwrap().to_vec()
}
