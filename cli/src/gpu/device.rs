//! The GPU every `--gpu` path runs on: wgpu's default adapter.

use crate::common::Result;
use nmat_wgpu::wgpu;
use std::path::Path;

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
/// decoding. With `choices` (`--kernel-choices FILE`), the kernels measured fastest in an earlier
/// run are taken from that file, and the choices written back to it where they changed.
pub fn upload(
    m: &nmat_core::Material<'_>,
    what: &str,
    choices: Option<&Path>,
) -> Result<(wgpu::Device, wgpu::Queue, nmat_wgpu::Context, nmat_wgpu::GpuMaterial)> {
    let start = std::time::Instant::now();
    let kept = choices.map(read_choices).transpose()?;
    let (device, queue, info) = open()?;
    let opened = start.elapsed().as_secs_f64();
    eprintln!("{what} on {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    let ctx = nmat_wgpu::Context::new(&device);
    if let Some((path, Some(text))) = &kept {
        let file = path.display();
        match ctx.remember_kernel_choices(&device, text) {
            Ok(0) if text.lines().skip(1).any(|l| !l.is_empty()) => eprintln!(
                "  {file}: kernel choices made on another adapter, driver or nmat version, not \
                 used here (measuring again; the file will hold this adapter's)"
            ),
            Ok(n) => eprintln!("  {n} kernel choice(s) taken from {file}"),
            Err(e) => {
                return Err(format!("--kernel-choices {file}: {e}; nothing was decoded").into());
            }
        }
    }
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
    if let Some((path, before)) = &kept {
        let text = ctx.kernel_choices(&device);
        if before.as_deref() != Some(text.as_str()) {
            nmat_cli::output::write_atomic(path, text.as_bytes())?;
            eprintln!("  kernel choices written to {}", path.display());
        }
    }
    Ok((device, queue, ctx, gm))
}

/// `--kernel-choices FILE`: the file's text where it exists (`None`: it will be written, so its
/// folder must exist), read before anything is run.
fn read_choices(path: &Path) -> Result<(&Path, Option<String>)> {
    let refused = |why: String| format!("--kernel-choices {}: {why}", path.display());
    match std::fs::read_to_string(path) {
        Ok(text) => Ok((path, Some(text))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
            if !dir.is_dir() {
                return Err(refused(format!("no folder {} to write it in", dir.display())).into());
            }
            Ok((path, None))
        }
        Err(e) => Err(refused(e.to_string()).into()),
    }
}
