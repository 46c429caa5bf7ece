//! A texel's input features as `nmat_decode` (texel.wgsl) and the batched kernels compute them:
//! `nmat_texel_features`, either texel.wgsl's generic `nmat_features` ([`GENERIC`], any
//! material) or code generated for a material's latent layout ([`Features`], features.wgsl),
//! bit-identical with it, with channel counts, bit widths, feature indices and the positional
//! encoding's constants as literals and each grid cell's codes read from its few words at once.
//! The batched kernels (tiled, unrolled, matrix) and a material's own sampling module
//! ([`crate::SampleBindings::module_for`]) take the generated one.

use nmat_core::{Neural, TermMode};
use std::fmt::Write as _;

/// One term of a level as the generated code reads it.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Term {
    bilinear: bool,
    /// Its features per cell: the first grid's channels.
    channels: u32,
    /// Per grid of its chain (one for `Nearest4`, which reads its first grid only): bits per
    /// latent code.
    bits: Vec<u32>,
}

/// The four cells of a footprint in the order `nmat_features` takes them.
const CELLS: [(&str, &str); 4] = [("x0", "y0"), ("x1", "y0"), ("x0", "y1"), ("x1", "y1")];

/// `nmat_texel_features` for any material: texel.wgsl's `nmat_features`.
pub(crate) const GENERIC: &str = "// nmat: a texel's input features, for any material.\n\
fn nmat_texel_features(xi: i32, yi: i32, mip_in: u32) {\n    nmat_features(xi, yi, mip_in);\n}\n";

/// A material's input features: features.wgsl and `fn nmat_texel_features(xi, yi, mip)` for
/// its layout, one function per distinct layout of a level, chosen by the texel's level. Where
/// checked, it first compares the bound material's fingerprint ([`Features::key`], its
/// descriptor's `features_key_lo` and `_hi`) with its own, and computes the generic features for
/// a material of another layout: a shader made for one material then decodes any other
/// exactly, only slower (the sampling module, which an engine may bind to any material).
/// Unchecked for the batched kernels, whose pipelines are shared by materials of this layout
/// only (they are keyed by their source), and where the generic features, which index
/// `nmat_act_a` at run time, would keep it out of registers. Should the material's levels and
/// network not agree (a chain's grids in other channel counts, levels of other widths than the
/// first layer's inputs: parsing refuses both), [`GENERIC`].
pub(crate) struct Features {
    /// The generated functions (`None`: the generic features) and their fingerprint.
    generated: Option<(String, [u32; 2])>,
}

impl Features {
    /// `n`'s features, generated once (a few kilobytes to tens of kilobytes of WGSL) for every
    /// source an upload makes.
    pub fn new(n: &Neural<'_>) -> Features {
        Features {
            generated: generate(n).map(|g| {
                let key = fingerprint(&g);
                (g, key)
            }),
        }
    }

    /// The fingerprint its descriptor carries (`features_key_lo` and `_hi`): 0 where the
    /// features are not generated (no generated code has it: its fingerprint is never 0).
    pub fn key(&self) -> [u32; 2] {
        self.generated.as_ref().map_or([0, 0], |(_, key)| *key)
    }

    /// The WGSL defining `nmat_texel_features`, checked or not ([`Features`]).
    pub fn wgsl(&self, checked: bool) -> String {
        let Some((generated, [lo, hi])) = &self.generated else { return GENERIC.to_string() };
        let body = if checked {
            format!(
                "    let key = vec2<u32>(nmat_desc[NMAT_DESC_FEATURES_KEY_LO], \
                 nmat_desc[NMAT_DESC_FEATURES_KEY_HI]);\n    \
                 if (all(key == vec2<u32>({lo}u, {hi}u))) {{\n        \
                 nmat_fixed_features(xi, yi, mip_in);\n    \
                 }} else {{\n        \
                 nmat_features(xi, yi, mip_in);\n    \
                 }}\n"
            )
        } else {
            "    nmat_fixed_features(xi, yi, mip_in);\n".to_string()
        };
        format!(
            "{}\n{generated}fn nmat_texel_features(xi: i32, yi: i32, mip_in: u32) {{\n{body}}}\n",
            include_str!("shaders/features.wgsl")
        )
    }
}

/// 64-bit FNV-1a of the generated code (equal codes, equal features), as two words, never 0.
pub(crate) fn fingerprint(generated: &str) -> [u32; 2] {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in generated.bytes() {
        h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
    }
    let h = h.max(1);
    [h as u32, (h >> 32) as u32]
}

/// The generated functions, or `None` where the levels and the network do not agree.
fn generate(n: &Neural<'_>) -> Option<String> {
    let grids = n.grids();
    // Each distinct layout of a level's terms, with the levels that have it.
    let mut layouts: Vec<(Vec<Term>, Vec<usize>)> = Vec::new();
    for (l, level) in n.levels().iter().enumerate() {
        let mut terms = Vec::new();
        for term in &level.terms {
            let first = grids.get(usize::from(*term.grids.first()?))?;
            let channels = first.channels() as u32;
            let chain: &[u8] =
                if term.mode == TermMode::Nearest4 { &term.grids[..1] } else { &term.grids };
            let mut bits = Vec::new();
            for &g in chain {
                let grid = grids.get(usize::from(g))?;
                if grid.channels() as u32 != channels {
                    return None;
                }
                bits.push(grid.bits_per_latent());
            }
            terms.push(Term { bilinear: term.mode != TermMode::Nearest4, channels, bits });
        }
        match layouts.iter_mut().find(|(t, _)| *t == terms) {
            Some((_, levels)) => levels.push(l),
            None => layouts.push((terms, vec![l])),
        }
    }
    let mut s = String::new();
    let mut width = None;
    for (v, (terms, _)) in layouts.iter().enumerate() {
        let features = layout_fn(&mut s, v, terms);
        if width.is_some_and(|w| w != features) {
            return None;
        }
        width = Some(features);
    }
    let mut at = width?;
    let mlp = n.mlp();
    let f_in = u32::from(mlp.input_frac_bits());
    s += "fn nmat_fixed_features(xi: i32, yi: i32, mip_in: u32) {\n    \
          let mip = min(mip_in, nmat_desc[NMAT_DESC_MIP_COUNT] - 1u);\n    \
          let mw = max(nmat_desc[NMAT_DESC_WIDTH] >> mip, 1u);\n    \
          let mh = max(nmat_desc[NMAT_DESC_HEIGHT] >> mip, 1u);\n    \
          let clamp_mode = nmat_desc[NMAT_DESC_ADDRESS_MODE] == 1u;\n    \
          let x = nmat_address(xi, mw, clamp_mode);\n    \
          let y = nmat_address(yi, mh, clamp_mode);\n    \
          let level = nmat_desc[NMAT_DESC_LEVEL_OF_MIP + mip];\n    \
          let lb = nmat_desc[NMAT_DESC_LEVELS_AT] + level * NMAT_LEVEL_WORDS;\n";
    let call = |v: usize| format!("nmat_fx{v}(x, y, mw, mh, clamp_mode, lb);");
    if layouts.len() == 1 {
        let _ = writeln!(s, "    {}", call(0));
    } else {
        s += "    switch level {\n";
        for (v, (_, levels)) in layouts.iter().enumerate() {
            let cases: Vec<String> = levels.iter().map(|l| format!("{l}u")).collect();
            let label = if v + 1 == layouts.len() { "default".into() } else { cases.join(", ") };
            let _ = writeln!(s, "        case {label}: {{ {} }}", call(v));
        }
        s += "    }\n";
    }
    for k in 0..u32::from(mlp.pe_frequencies()) {
        for (axis, phase) in [("x", 0), ("x", 1), ("y", 0), ("y", 1)] {
            let _ = writeln!(
                s,
                "    nmat_act_a[{at}] = nmat_triangle({axis}, {k}u, {phase}u, {f_in}u);"
            );
            at += 1;
        }
    }
    let lod = u32::from(mlp.lod_code());
    if lod != 0 {
        // mip · 2^(code − 5) in f_in fraction bits (texel.wgsl; f_in ≥ 4, code ≥ 1).
        let shift = (f_in + lod).checked_sub(5)?;
        let _ = writeln!(s, "    nmat_act_a[{at}] = i32(mip << {shift}u);");
        at += 1;
    }
    let inputs = mlp.layers().first()?.inputs() as u32;
    (at == inputs).then(|| s + "}\n")
}

/// `fn nmat_fx{v}(…)`: the terms' features of a level with layout `terms` (its record at `lb`)
/// into `nmat_act_a` from index 0; returns how many.
fn layout_fn(s: &mut String, v: usize, terms: &[Term]) -> u32 {
    let _ = writeln!(
        s,
        "fn nmat_fx{v}(x: u32, y: u32, mw: u32, mh: u32, clamp_mode: bool, lb: u32) {{"
    );
    let mut at = 0;
    for (t, term) in terms.iter().enumerate() {
        let ch = term.channels;
        let _ = writeln!(s, "    let tb{t} = lb + NMAT_LEVEL_TERMS + {t}u * NMAT_TERM_WORDS;");
        if !term.bilinear {
            // The 4 cells' codes in cell order, channels within a cell.
            let values = grid_values(s, t, 0, ch, term.bits[0]);
            for (cell, row) in values.iter().enumerate() {
                for (c, value) in row.iter().enumerate() {
                    let _ = writeln!(
                        s,
                        "    nmat_act_a[{}] = {value};",
                        at + cell as u32 * ch + c as u32
                    );
                }
            }
            at += 4 * ch;
            continue;
        }
        let chain = term.bits.len();
        if chain > 1 {
            // Σ over the chain of (s >> 16) and (s & 0xFFFF) kept apart (texel.wgsl).
            for c in 0..ch {
                let _ = writeln!(s, "    var h{t}_{c} = 0;\n    var l{t}_{c} = 0;");
            }
        }
        for (k, &bits) in term.bits.iter().enumerate() {
            let values = grid_values(s, t, k, ch, bits);
            let _ = writeln!(s, "    let g{t}_{k} = nmat_bilinear_weights(f{t}_{k});");
            for c in 0..ch as usize {
                let sum: Vec<String> = values
                    .iter()
                    .zip(["x", "y", "z", "w"])
                    .map(|(cell, w)| format!("g{t}_{k}.{w} * {}", cell[c]))
                    .collect();
                let _ = writeln!(s, "    let s{t}_{k}_{c} = {};", sum.join(" + "));
                if chain == 1 {
                    let _ = writeln!(
                        s,
                        "    nmat_act_a[{}] = nmat_round_split(s{t}_{k}_{c} >> 16u, \
                         bitcast<u32>(s{t}_{k}_{c}) & 0xFFFFu);",
                        at + c as u32
                    );
                } else {
                    let _ = writeln!(
                        s,
                        "    h{t}_{c} += s{t}_{k}_{c} >> 16u;\n    \
                         l{t}_{c} += bitcast<i32>(bitcast<u32>(s{t}_{k}_{c}) & 0xFFFFu);"
                    );
                }
            }
        }
        if chain > 1 {
            for c in 0..ch {
                let _ = writeln!(
                    s,
                    "    nmat_act_a[{}] = nmat_round_split(h{t}_{c}, bitcast<u32>(l{t}_{c}));",
                    at + c
                );
            }
        }
        at += ch;
    }
    s.push_str("}\n");
    at
}

/// Grid `k` of term `t`'s chain (`ch` channels of `bits` bits a code): its record `r{t}_{k}`,
/// footprint `f{t}_{k}` and each channel's dequantization, then per cell its words loaded and
/// aligned to the cell's first bit and each channel's dequantized value. Returns the values'
/// expressions by cell, then channel.
fn grid_values(s: &mut String, t: usize, k: usize, ch: u32, bits: u32) -> Vec<Vec<String>> {
    let p = format!("{t}_{k}");
    let _ = writeln!(
        s,
        "    let r{p} = nmat_fx_grid(tb{t}, {k}u);\n    \
         let f{p} = nmat_footprint(r{p}, x, y, mw, mh, clamp_mode);"
    );
    for c in 0..ch {
        let _ = writeln!(s, "    let q{p}_{c} = nmat_grid_quant(r{p}, {c}u);");
    }
    let cell_bits = ch * bits;
    // A cell starts at a multiple of cell_bits: at one of these bits of a word.
    let step = gcd(cell_bits, 32);
    let last_shift = 32 - step;
    let aligned = cell_bits.div_ceil(32);
    let loaded = (last_shift + cell_bits).div_ceil(32);
    let mask = (1u64 << bits) - 1;
    let mut values = Vec::new();
    for (cell, (cx, cy)) in CELLS.iter().enumerate() {
        let e = format!("e{p}_{cell}");
        let _ =
            writeln!(s, "    let {e} = nmat_fx_cell(r{p}, f{p}.{cx}, f{p}.{cy}, {cell_bits}u);");
        // Words past the grid's last one (robust reads) only meet bits past the cell's codes,
        // which the masks below drop.
        for i in 0..loaded {
            let _ = writeln!(s, "    let w{p}_{cell}_{i} = nmat_latents[{e}.x + {i}u];");
        }
        for i in 0..aligned {
            let word = if last_shift == 0 {
                format!("w{p}_{cell}_{i}")
            } else {
                let hi =
                    if i + 1 < loaded { format!("w{p}_{cell}_{}", i + 1) } else { "0u".into() };
                format!("nmat_fx_funnel(w{p}_{cell}_{i}, {hi}, {e}.y)")
            };
            let _ = writeln!(s, "    let a{p}_{cell}_{i} = {word};");
        }
        let mut row = Vec::new();
        for c in 0..ch {
            let (i, sh) = ((c * bits) / 32, (c * bits) % 32);
            let a = format!("a{p}_{cell}_{i}");
            let code = if sh + bits <= 32 {
                format!("(({a} >> {sh}u) & {mask:#x}u)")
            } else {
                format!("((({a} >> {sh}u) | (a{p}_{cell}_{} << {}u)) & {mask:#x}u)", i + 1, 32 - sh)
            };
            let v = format!("v{p}_{cell}_{c}");
            let _ = writeln!(s, "    let {v} = q{p}_{c}.x + i32({code}) * q{p}_{c}.y;");
            row.push(v);
        }
        values.push(row);
    }
    values
}

fn gcd(a: u32, b: u32) -> u32 {
    if b == 0 { a } else { gcd(b, a % b) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nmat_core::Container;
    use nmat_tests::generate::{generate as fixture, golden_and_random_configs};

    /// Every golden fixture (NTC layouts of 1 to 8 bits a code, cells that start inside a word,
    /// 16 channels, NBC chains whose levels differ in layout) and 64 random valid materials get
    /// generated features, not the generic ones, and the NBC fixtures one function per layout,
    /// picked by the texel's level. Their codes are tested through every kernel
    /// (tests/bitexact.rs, tests/cache.rs, tests/extremes.rs).
    #[test]
    fn every_fixture_gets_generated_features() {
        for cfg in golden_and_random_configs(64) {
            let bytes = fixture(&cfg).to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            let n = m.neural().expect("a neural fixture");
            let features = Features::new(n);
            let source = features.wgsl(false);
            assert_eq!(source.matches("fn nmat_texel_features").count(), 1, "{}", cfg.name);
            assert!(!source.contains("nmat_features("), "{}: the generic features", cfg.name);
            // Checked (the sampling module): the generic features where the bound material has
            // another layout.
            let checked = features.wgsl(true);
            assert_eq!(checked.matches("nmat_features(").count(), 1, "{}", cfg.name);
            if cfg.name.starts_with("nbc") {
                assert!(source.contains("switch level"), "{}: one layout", cfg.name);
            }
            // It goes into engines' shaders (SampleBindings::module_for): nmat's names only.
            let foreign: Vec<&str> = checked
                .lines()
                .filter(|l| l.starts_with("fn ") && !l.starts_with("fn nmat_"))
                .collect();
            assert!(foreign.is_empty(), "{}: {foreign:?}", cfg.name);
        }
    }
}
