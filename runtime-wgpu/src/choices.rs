//! The kernels `upload` measured fastest, kept between runs: [`Context::kernel_choices`] writes
//! them as text, [`Context::remember_kernel_choices`] takes them back (docs/GPU.md, "The
//! kernels, and how `upload` picks one").

use crate::{Context, GpuError, Kernel};

/// How the text's first line begins; the rest of that line names nmat-wgpu's version and the
/// adapter and driver the choices were measured on.
const HEADER: &str = "nmat-wgpu kernel choices";

/// The first line of [`Context::kernel_choices`]'s text on `device`: choices measured with
/// another version of the kernels, or on another adapter or driver, say nothing about these.
fn identity(device: &wgpu::Device) -> String {
    let info = device.adapter_info();
    let line = format!(
        "{HEADER} {} on {:?} {:#06x}:{:#06x} {} ({} {})",
        env!("CARGO_PKG_VERSION"),
        info.backend,
        info.vendor,
        info.device,
        info.name,
        info.driver,
        info.driver_info
    );
    line.replace(['\n', '\r'], " ")
}

impl Context {
    /// The kernel [`Context::upload`] measured fastest for each network shape on `device` (or
    /// was given by [`Context::remember_kernel_choices`]), as
    /// text an engine saves between runs (next to its pipeline cache's data) and gives to
    /// [`Context::remember_kernel_choices`] in a later run, so that `upload` there prepares and
    /// probes that kernel alone and measures nothing. The first line names nmat-wgpu's version,
    /// the adapter and its driver; then one line per shape: the kernel's [`Kernel::id`], a tab,
    /// and the shape (the network's layer widths as `[(inputs, outputs), …]`, a space, the
    /// channel count), sorted. Only measured choices are listed: a software adapter measures
    /// nothing (its text is the first line alone).
    pub fn kernel_choices(&self, device: &wgpu::Device) -> String {
        let choices = self.choices.lock().unwrap_or_else(|e| e.into_inner());
        let mut lines: Vec<String> =
            choices.iter().map(|(shape, kernel)| format!("{}\t{shape}\n", kernel.id())).collect();
        lines.sort();
        let mut text = identity(device);
        text.push('\n');
        text.extend(lines);
        text
    }

    /// Takes the choices of an earlier run ([`Context::kernel_choices`]'s text): a later
    /// [`Context::upload`] of a material of a listed shape tries that kernel first and, where
    /// its probe passes, uses it without timing the others (where it fails, the next kernel in
    /// [`Kernel::ALL`] from its end whose probe passes, untimed: a remembered choice is never
    /// taken on trust). Returns how many choices
    /// were taken: all the text lists, or none where it was written by another version of
    /// nmat-wgpu or on another adapter or driver (logged), whose timings say nothing about this
    /// one. A text that is not such a text is `GpuError::KernelChoices`, naming the line, and
    /// nothing is taken.
    pub fn remember_kernel_choices(
        &self,
        device: &wgpu::Device,
        text: &str,
    ) -> Result<usize, GpuError> {
        let mut lines = text.lines();
        let first = lines.next().unwrap_or_default();
        if !first.starts_with(HEADER) {
            return Err(GpuError::KernelChoices {
                line: 1,
                reason: "not nmat-wgpu's kernel choices (the first line names them)",
            });
        }
        let mut taken = Vec::new();
        for (i, line) in lines.enumerate().filter(|(_, l)| !l.is_empty()) {
            let refused = |reason| GpuError::KernelChoices { line: i + 2, reason };
            let (id, shape) =
                line.split_once('\t').ok_or(refused("not a kernel, a tab and a network shape"))?;
            let kernel = Kernel::from_id(id).ok_or(refused("not a kernel's name"))?;
            if shape.is_empty() {
                return Err(refused("no network shape after the tab"));
            }
            taken.push((shape.to_owned(), kernel));
        }
        let here = identity(device);
        if first != here {
            log::info!(
                "nmat-wgpu: kernel choices made elsewhere are not used here ({first:?}, not \
                 {here:?})"
            );
            return Ok(0);
        }
        let count = taken.len();
        self.choices.lock().unwrap_or_else(|e| e.into_inner()).extend(taken);
        Ok(count)
    }
}
