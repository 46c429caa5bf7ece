//! The unrolled kernels (unrolled.wgsl): one texel per invocation, each row's sum written out
//! per material shape so that a layer's inputs live in registers and weights are read at
//! constant offsets; products from `dot4I8Packed` or 32-bit multiply-adds on the tiled kernels'
//! tables (tiled.rs).

use crate::measure::Part;
use nmat_core::{Activation, Material, Neural};
use std::fmt::Write as _;

/// `nmat_texel_network` for any material: texel.wgsl's `nmat_layers`.
pub(crate) const GENERIC_NETWORK: &str = "// nmat: a texel's network, for any material.\n\
fn nmat_texel_network(mask: u32) {\n    nmat_layers(mask);\n}\n";

/// The most weight words per row (four int8 weights each) a layer may have to be unrolled: a
/// row's sum is written out word by word, and its inputs held as named values (two registers a
/// word), so the widest layer the format allows (128 inputs: 32 words) is the limit.
const MAX_WORDS: usize = 32;

/// One layer as the generated code needs it.
struct Layer {
    inputs: usize,
    outputs: usize,
    frac: u32,
    gelu: bool,
}

/// What an unrolled pipeline is specialised to: every width a literal in its source.
pub(crate) struct Shape {
    /// Products from `dot4I8Packed` (else 32-bit multiply-adds).
    dot4: bool,
    channels: u32,
    layers: Vec<Layer>,
}

/// Where a generated network's codes go.
#[derive(Clone, Copy)]
enum Sink {
    /// The unrolled kernels' `network(t)`: into tile_codes (unrolled.wgsl).
    Kernel,
    /// The sampling module's `nmat_u_network(mask)`: into nmat_codes (texel.wgsl).
    Texel,
}

/// A material's network unrolled for the sampling module made for it
/// ([`crate::SampleBindings::module_for`]): `nmat_texel_network` computing `nmat_layers`' codes,
/// bit for bit, with the unrolled kernels' code on the tiled kernels' tables (which the
/// material's descriptor holds where its kernel is not the reference one: their weights packed
/// and, with `dot4I8Packed`, 128 · Σ w in the bias). Like the generated features it first
/// compares a fingerprint of its code (and of the tables' kind) with the bound material's
/// (`network_key_lo` and `_hi` of its descriptor, written with the tables) and runs the generic
/// layers for any other material: exact with any.
pub(crate) struct SampleNetwork {
    /// The generated code and its fingerprint.
    code: String,
    key: [u32; 2],
}

impl SampleNetwork {
    /// `m`'s network for tables with (`dot4`) or without 128 · Σ w in the bias; `None` where
    /// it is not unrolled ([`Shape::new`]).
    pub fn new(m: (&Material<'_>, &Neural<'_>), dot4: bool) -> Option<SampleNetwork> {
        let shape = Shape::new(m, dot4).ok()?;
        let code = format!("{}\n{}", shape.helpers(), shape.network(Sink::Texel));
        let key = crate::features::fingerprint(&code);
        Some(SampleNetwork { code, key })
    }

    /// The fingerprint the tables' writer puts in the descriptor (never 0).
    pub fn key(&self) -> [u32; 2] {
        self.key
    }

    /// The WGSL defining `nmat_texel_network`, checked against the bound material's key.
    pub fn wgsl(&self) -> String {
        let [lo, hi] = self.key;
        format!(
            "{}\n// nmat: a texel's network, unrolled for one material (SampleBindings::module_for).\n\
             fn nmat_texel_network(mask: u32) {{\n    \
             let key = vec2<u32>(nmat_desc[NMAT_DESC_NETWORK_KEY_LO], \
             nmat_desc[NMAT_DESC_NETWORK_KEY_HI]);\n    \
             if (all(key == vec2<u32>({lo}u, {hi}u))) {{\n        nmat_u_network(mask);\n    \
             }} else {{\n        nmat_layers(mask);\n    }}\n}}\n",
            self.code
        )
    }
}

impl Shape {
    /// The shape of `m`'s network, or why it is not unrolled (a layer wider than [`MAX_WORDS`]
    /// words, or none).
    pub fn new((m, n): (&Material<'_>, &Neural<'_>), dot4: bool) -> Result<Shape, &'static str> {
        let layers: Vec<Layer> = n
            .mlp()
            .layers()
            .iter()
            .map(|l| Layer {
                inputs: l.inputs(),
                outputs: l.outputs(),
                frac: u32::from(l.out_frac_bits()),
                gelu: l.activation() == Activation::HardGelu,
            })
            .collect();
        let widest = layers.iter().map(|l| l.inputs.div_ceil(4)).max();
        if widest.is_none_or(|words| words > MAX_WORDS) {
            return Err("the network's layers are too wide to unroll");
        }
        Ok(Shape { dot4, channels: m.channel_count() as u32, layers })
    }

    /// The WGSL of the pipeline (entry points `unrolled` and `unrolled_cache`) with `features`
    /// (features.rs, unchecked); only `part` of the work where it is not [`Part::Whole`] (for
    /// timing: the codes are then wrong).
    pub fn source_part(&self, part: Part, features: &str) -> String {
        format!(
            "const P: u32 = 64u;\nconst CH: u32 = {}u;\nconst PART: u32 = {}u;\n{}{}\n{}\n{}\n{}\n{}\n{}",
            self.channels,
            part.code(),
            Part::STAND_IN_WGSL,
            self.network(Sink::Kernel),
            crate::layout::texel_wgsl_with(features, GENERIC_NETWORK),
            crate::layout::decode_wgsl(),
            self.helpers(),
            include_str!("shaders/unrolled.wgsl"),
            crate::layout::batch_wgsl(),
        )
    }

    /// What a generated network calls: requant.wgsl, the products file and
    /// unrolled_network.wgsl.
    fn helpers(&self) -> String {
        let products = if self.dot4 {
            include_str!("shaders/unrolled_dot4.wgsl")
        } else {
            include_str!("shaders/unrolled_i32.wgsl")
        };
        format!(
            "{}\n{products}\n{}",
            include_str!("shaders/requant.wgsl"),
            include_str!("shaders/unrolled_network.wgsl")
        )
    }

    /// `fn network(t)` (for `sink` [`Sink::Kernel`]: texel `t`'s codes into tile_codes) or
    /// `fn nmat_u_network(mask)` ([`Sink::Texel`]: the codes of the channels in `mask` into
    /// nmat_codes, as `nmat_layers`): the input features in nmat_act_a through every layer.
    /// Layer l's inputs are the words `x{l}_{j}` (four activations each, as the products file
    /// holds them: `NmatWord`), named values a GPU keeps in registers; each output row's sum
    /// over them is written out (one load of a weight word and its products per word), the rows
    /// taken by a loop, their values through `nmat_act_b` (free once the features are made)
    /// into the next layer's words.
    fn network(&self, sink: Sink) -> String {
        let (mut s, code) = match sink {
            Sink::Kernel => (String::from("fn network(t: u32) {\n"), "nmat_u_code(t"),
            Sink::Texel => {
                (String::from("fn nmat_u_network(mask: u32) {\n"), "nmat_u_texel_code(mask")
            }
        };
        let first = &self.layers[0];
        for j in 0..first.inputs.div_ceil(4) {
            let _ = writeln!(s, "    let x0_{j} = nmat_u_features({j}u, {}u);", first.inputs);
        }
        for (l, layer) in self.layers.iter().enumerate() {
            let kw = layer.inputs.div_ceil(4);
            let terms: Vec<String> =
                (0..kw).map(|j| format!("nmat_u_mac(nmat_desc[w + {j}u], x{l}_{j})")).collect();
            let _ = writeln!(
                s,
                "    let lb{l} = nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_WORDS * {l}u;\n    \
                 let wa{l} = nmat_desc[lb{l} + NMAT_LAYER_PACKED_AT];\n    \
                 let ra{l} = nmat_desc[lb{l} + NMAT_LAYER_REQUANT_AT];\n    \
                 for (var o = 0u; o < {}u; o++) {{\n        \
                 let w = wa{l} + o * {kw}u;\n        \
                 nmat_act_b[o] = nmat_u_row(ra{l}, o, {}u, {}, {});\n    }}",
                layer.outputs,
                layer.frac,
                layer.gelu,
                terms.join(" + ")
            );
            if l + 1 == self.layers.len() {
                let _ = writeln!(
                    s,
                    "    for (var o = 0u; o < {}u; o++) {{\n        \
                     {code}, o, {}u, nmat_act_b[o]);\n    }}",
                    layer.outputs.min(self.channels as usize),
                    layer.frac
                );
                continue;
            }
            for g in 0..layer.outputs.div_ceil(4) {
                let z: Vec<String> =
                    (4 * g..4 * g + 4)
                        .map(|o| {
                            if o < layer.outputs { format!("nmat_act_b[{o}]") } else { "0".into() }
                        })
                        .collect();
                let _ = writeln!(
                    s,
                    "    let x{}_{g} = nmat_u_word(vec4<i32>({}));",
                    l + 1,
                    z.join(", ")
                );
            }
        }
        s + "}\n"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nmat_core::Container;
    use nmat_tests::generate::{FixtureConfig, generate, golden_and_random_configs};

    /// Every golden fixture's network, 64 random valid materials' and the widest the format
    /// allows (three hidden layers of 128) unroll into WGSL that naga validates, with both entry
    /// points, in each part.
    #[test]
    fn the_unrolled_kernel_validates_for_every_fixture_shape() {
        let mut configs = golden_and_random_configs(64);
        configs.push(FixtureConfig {
            hidden: vec![128, 128, 128],
            ..FixtureConfig::ntc("widest", 9, 32, 32, 16)
        });
        for cfg in configs {
            let bytes = generate(&cfg).to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            let n = m.neural().expect("a neural fixture");
            let parts = [Part::Whole, Part::Features, Part::Layers];
            for (dot4, part) in [true, false].into_iter().flat_map(|d| parts.map(|p| (d, p))) {
                let features = crate::features::Features::new(n).wgsl(false);
                let source = Shape::new((&m, n), dot4).unwrap().source_part(part, &features);
                let module = crate::naga_check::validate(&format!("{cfg:?} {part:?}"), &source);
                let entries: Vec<&str> =
                    module.entry_points.iter().map(|e| e.name.as_str()).collect();
                assert!(entries.contains(&"unrolled") && entries.contains(&"unrolled_cache"));
            }
        }
    }
}
