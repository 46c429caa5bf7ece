//! Inference on sample: the decoder as a WGSL module an engine includes in its own shaders
//! (`nmat_sample`, `nmat_texel`; sample.wgsl), bound to a material uploaded by [`Context::upload`].
//!
//! [`Context::upload`]: crate::Context::upload

use crate::{GpuError, GpuMaterial};

/// Where a shader that includes [`SampleBindings::module`] finds its material: two read-only
/// storage buffers, bindings `first_binding` and `first_binding + 1` of bind group `group`, so
/// the material can share a group with the engine's own resources.
///
/// ```no_run
/// # fn demo(device: &wgpu::Device, gpu: &nmat_wgpu::GpuMaterial) -> Result<(), nmat_wgpu::GpuError> {
/// use nmat_wgpu::SampleBindings;
/// let bindings = SampleBindings { group: 1, first_binding: 0 };
/// // The engine's fragment shader calls nmat_sample(uv, lod, rnd, NMAT_TRILINEAR, mask).
/// let source = format!("{}\n{}", bindings.module(), "/* the engine's shader */");
/// let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
///     label: Some("material"),
///     entries: &bindings.layout_entries(wgpu::ShaderStages::FRAGMENT),
/// });
/// let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
///     label: Some("material"),
///     layout: &layout,
///     entries: &gpu.sample_entries(bindings)?, // a neural material
/// });
/// # let _ = (source, group); Ok(()) }
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SampleBindings {
    pub group: u32,
    pub first_binding: u32,
}

impl SampleBindings {
    /// The WGSL module: the two bindings, the bit-exact texel decoder and the filtered lookup.
    /// Its entries are `nmat_sample(uv, lod, rnd, mode, channels) -> array<f32, 16>` and
    /// `nmat_texel(xy, mip, channels) -> array<u32, 16>`, with `nmat_channel_count()`,
    /// `nmat_mip_count()`, `nmat_mip_size(mip)` and the constants `NMAT_NEAREST`,
    /// `NMAT_BILINEAR`, `NMAT_TRILINEAR`, `NMAT_STOCHASTIC`, `NMAT_ALL_CHANNELS` (semantics in
    /// the comments of the module and in `docs/GPU.md`). Every name it declares at module scope
    /// starts with `nmat_`, `Nmat` or `NMAT_`. Concatenate it with the shader that calls it (WGSL
    /// declarations may come in any order). One material per module: a shader sampling two
    /// materials binds them one after the other (or includes two modules renamed by the engine).
    pub fn module(&self) -> String {
        self.module_with(crate::features::GENERIC, crate::unrolled::GENERIC_NETWORK)
    }

    /// [`SampleBindings::module`] specialised to `material`'s latent layout: the same entries,
    /// names and results, bit for bit, with the input features of each decode computed by code
    /// generated for that layout (each grid channel's count and bits per code, the levels'
    /// terms, as literals; docs/GPU.md, "Input features") instead of read from the descriptor —
    /// the code the batched kernels decode regions with. Made for `material` and the materials
    /// of its layout (e.g. encoded with the same `nmat encode` options), but exact with any: it
    /// compares a fingerprint of its code with the one the bound material's descriptor carries
    /// and, for a material of another layout, computes the generic features (same codes, the
    /// generic speed). [`GpuError::Codec`] for a JPEG material.
    pub fn module_for(&self, material: &GpuMaterial) -> Result<String, GpuError> {
        material.neural()?;
        let features = material.features.as_deref().ok_or(GpuError::Codec)?;
        let network = material.network.as_deref().unwrap_or(crate::unrolled::GENERIC_NETWORK);
        Ok(self.module_with(features, network))
    }

    /// The module with `features` as its `nmat_texel_features` and `network` as its
    /// `nmat_texel_network`.
    fn module_with(&self, features: &str, network: &str) -> String {
        let (g, b) = (self.group, self.first_binding);
        format!(
            "// nmat: the material's bindings (nmat_wgpu::SampleBindings).\n\
             @group({g}) @binding({b}) var<storage, read> nmat_desc: array<u32>;\n\
             @group({g}) @binding({}) var<storage, read> nmat_latents: array<u32>;\n\n{}\n{}\n{}",
            b + 1,
            crate::layout::texel_wgsl_with(features, network),
            include_str!("shaders/sample.wgsl"),
            include_str!("shaders/filter.wgsl"),
        )
    }

    /// The two entries of a bind group layout for the module's bindings (read-only storage
    /// buffers visible to `visibility`), to put in the engine's layout of `group`.
    pub fn layout_entries(
        &self,
        visibility: wgpu::ShaderStages,
    ) -> [wgpu::BindGroupLayoutEntry; 2] {
        [0, 1].map(|k| wgpu::BindGroupLayoutEntry {
            binding: self.first_binding + k,
            visibility,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
    }
}

impl GpuMaterial {
    /// The two bind group entries that bind this material where `bindings` says, to put in the
    /// engine's bind group of `bindings.group`. [`GpuError::Codec`] for a JPEG material: the
    /// sampling module decodes neural materials only.
    pub fn sample_entries(
        &self,
        bindings: SampleBindings,
    ) -> Result<[wgpu::BindGroupEntry<'_>; 2], GpuError> {
        self.neural()?;
        Ok([
            wgpu::BindGroupEntry {
                binding: bindings.first_binding,
                resource: self.desc.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: bindings.first_binding + 1,
                resource: self.latents.as_entire_binding(),
            },
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::SampleBindings;

    /// The name a module-scope declaration line introduces, if the line is one.
    fn declared(line: &str) -> Option<&str> {
        if line.starts_with(char::is_whitespace) {
            return None;
        }
        let rest = line.strip_prefix("fn ").or_else(|| line.strip_prefix("const "));
        let rest = rest.or_else(|| line.strip_prefix("struct "));
        let rest = rest.or_else(|| line.strip_prefix("alias "));
        let rest = rest.or_else(|| {
            line.split_once("var<").and_then(|(_, r)| r.split_once("> ")).map(|(_, r)| r)
        });
        rest.map(|r| r.split(|c: char| !(c.is_alphanumeric() || c == '_')).next().unwrap_or(""))
    }

    /// The names a module declares at module scope that do not start with `nmat_`, `Nmat` or
    /// `NMAT_`.
    fn foreign(source: &str) -> Vec<&str> {
        let names = source.lines().filter_map(declared);
        names
            .filter(|n| {
                !(n.starts_with("nmat_") || n.starts_with("Nmat") || n.starts_with("NMAT_"))
            })
            .collect()
    }

    /// The module made for a material (its features generated, its network unrolled on either
    /// kind of table) declares only namespaced names too, and naga validates it, for every
    /// golden fixture and 64 random valid materials.
    #[test]
    fn a_module_for_a_material_is_namespaced_too() {
        use nmat_tests::generate::{generate, golden_and_random_configs};
        for cfg in golden_and_random_configs(64) {
            let bytes = generate(&cfg).to_bytes().unwrap();
            let m = nmat_core::Container::parse(&bytes).unwrap();
            let n = m.neural().unwrap();
            let features = crate::features::Features::new(n).wgsl(true);
            for dot4 in [false, true] {
                let network = crate::unrolled::SampleNetwork::new((&m, n), dot4).unwrap().wgsl();
                let source =
                    SampleBindings { group: 0, first_binding: 0 }.module_with(&features, &network);
                assert!(source.contains("fn nmat_u_network(") && source.contains("alias NmatWord"));
                assert!(foreign(&source).is_empty(), "{}: {:?}", cfg.name, foreign(&source));
                crate::naga_check::validate(&format!("{cfg:?}"), &source);
            }
        }
    }

    #[test]
    fn every_module_scope_name_is_namespaced() {
        let source = SampleBindings { group: 2, first_binding: 5 }.module();
        let names: Vec<&str> = source.lines().filter_map(declared).collect();
        for must in [
            "nmat_sample",
            "nmat_texel",
            "nmat_decode",
            "nmat_desc",
            "nmat_latents",
            "NMAT_TRILINEAR",
        ] {
            assert!(names.contains(&must), "{must} not declared: {names:?}");
        }
        let foreign = foreign(&source);
        assert!(foreign.is_empty(), "names an engine's shader could collide with: {foreign:?}");
        assert!(source.contains("@group(2) @binding(5) var<storage, read> nmat_desc"));
        assert!(source.contains("@group(2) @binding(6) var<storage, read> nmat_latents"));
    }
}
