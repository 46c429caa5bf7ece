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
pub fn trained_material() -> Vec<u8> {
    let set = nmat_encode::demo::bricks(64);
    let options = nmat_encode::EncodeOptions {
        train: nmat_encode::TrainOptions { steps: 150, ..Default::default() },
        ..Default::default()
    };
    nmat_encode::encode(&set, &options, &mut |_| {}).unwrap().bytes
}
