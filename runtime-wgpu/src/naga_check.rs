//! What the unit tests ask of naga (the compiler wgpu runs) about a generated shader: parsed
//! and validated, its errors rendered against the source, and free of the operations whose
//! result differs between the backends wgpu compiles to.

/// `source` parsed and validated with `capabilities`, or naga's error rendered against it; a
/// source with a remainder of signed integers is refused too ([`signed_remainders`]).
pub fn validate_with(
    source: &str,
    capabilities: naga::valid::Capabilities,
) -> Result<(naga::Module, naga::valid::ModuleInfo), String> {
    let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
    let flags = naga::valid::ValidationFlags::all();
    let info = naga::valid::Validator::new(flags, capabilities)
        .validate(&module)
        .map_err(|e| e.emit_to_string(source))?;
    let bare = uninitialized_vars(source);
    if !bare.is_empty() {
        return Err(format!(
            "a function-scope `var` without an initializer (WGSL zeroes it each time the \
             declaration runs, but Chromium's WebGPU kept its value from the loop's previous \
             iteration: write `var x = T();`): {}",
            bare.join("; ")
        ));
    }
    let signed = signed_remainders(&module, &info);
    if !signed.is_empty() {
        return Err(format!(
            "a remainder of signed integers (GLSL leaves it undefined for negative operands, \
             naga's GLSL writes it as is, and Mesa's OpenGL driver returns other values than \
             WGSL's; wrap with unsigned arithmetic) in {}",
            signed.join(", ")
        ));
    }
    Ok((module, info))
}

/// The function-scope `var` declarations of `source` (indented lines, not `var<…>`) without an
/// initializer: `var x: T;`. WGSL gives such a variable its zero value each time the
/// declaration is executed, but Chromium's WebGPU (Tint, on SwiftShader; 2026-12-05) did not
/// for one declared inside a loop — the BC7 encoder's per-partition sums carried over from the
/// previous partition, and 451 of 480 blocks of a material differed from the CPU's — so every
/// shader the crate builds spells the zero out (`var x = T();`).
pub fn uninitialized_vars(source: &str) -> Vec<String> {
    source
        .lines()
        .filter(|line| line.starts_with(char::is_whitespace))
        .filter_map(|line| {
            let code = line.split("//").next().unwrap_or_default().trim();
            let rest = code.strip_prefix("var ")?;
            (rest.contains(':') && !rest.contains('=') && rest.ends_with(';')).then(|| code.into())
        })
        .collect()
}

/// [`validate_with`] every capability a device may have; panics naming `what` where naga
/// refuses `source`.
pub fn validate(what: &str, source: &str) -> naga::Module {
    validate_with(source, naga::valid::Capabilities::all())
        .unwrap_or_else(|e| panic!("{what}: {e}"))
        .0
}

/// The functions of `module` (by name) that take `a % b` of signed integers (scalars or
/// vectors). WGSL defines it (the sign of `a`), and SPIR-V's `OpSRem` and the `%` of MSL and
/// HLSL compute it alike, but OpenGL ES — wgpu's GL backend, where naga writes GLSL's `%`
/// unchanged — leaves it undefined for negative operands: on Mesa 22.3's llvmpipe
/// `((i % s) + s) % s` wrapped −264 into 78 cells as 70 (not 48), and the floor division
/// `floor(−125 952 / 1536)` came out one less than −82, so decoded codes differed by one.
pub fn signed_remainders(module: &naga::Module, info: &naga::valid::ModuleInfo) -> Vec<String> {
    let functions = module.functions.iter().map(|(handle, f)| (f, &info[handle])).chain(
        module.entry_points.iter().enumerate().map(|(i, e)| (&e.function, info.get_entry_point(i))),
    );
    let mut found = Vec::new();
    for (function, function_info) in functions {
        let signed = function.expressions.iter().any(|(_, expression)| {
            matches!(
                expression,
                naga::Expression::Binary { op: naga::BinaryOperator::Modulo, left, .. }
                    if function_info[*left].ty.inner_with(&module.types).scalar_kind()
                        == Some(naga::ScalarKind::Sint)
            )
        });
        if signed {
            found.push(function.name.clone().unwrap_or_else(|| "an unnamed function".into()));
        }
    }
    found
}

#[cfg(test)]
mod tests {
    /// A signed remainder is found (in the function that takes it, also through a vector), an
    /// unsigned one is not.
    #[test]
    fn signed_remainders_are_found_and_unsigned_ones_are_not() {
        let source = "
            fn wrap(i: i32, s: i32) -> i32 { return ((i % s) + s) % s; }
            fn lanes(v: vec2<i32>) -> vec2<i32> { return v % vec2<i32>(3); }
            fn fine(i: u32) -> u32 { return i % 7u; }
            @compute @workgroup_size(1)
            fn main() { _ = wrap(-3, 2) + lanes(vec2(1)).x; _ = fine(3u); }";
        let err = super::validate_with(source, naga::valid::Capabilities::all()).unwrap_err();
        assert!(err.ends_with("in wrap, lanes"), "{err}");
        let unsigned = "fn fine(i: u32) -> u32 { var r = 0u; r = i % 7u; return r; }
            @compute @workgroup_size(1) fn main() { _ = fine(3u); }";
        assert!(super::validate_with(unsigned, naga::valid::Capabilities::all()).is_ok());
    }

    /// A function-scope `var` without an initializer is refused, naming it (in a loop too); one
    /// with an initializer, and module-scope ones, are not.
    #[test]
    fn function_scope_vars_without_an_initializer_are_refused() {
        let source = "var<private> kept: u32;
            fn sums() -> u32 {
                var total = 0u;
                for (var i = 0u; i < 4u; i++) {
                    var sum: array<u32, 3>; // zeroed by WGSL, not by every compiler
                    sum[i % 3u] += i;
                    total += sum[0];
                }
                return total + kept;
            }
            @compute @workgroup_size(1) fn main() { _ = sums(); }";
        let err = super::validate_with(source, naga::valid::Capabilities::all()).unwrap_err();
        assert!(err.ends_with("var sum: array<u32, 3>;"), "{err}");
        let fixed = source.replace("var sum: array<u32, 3>;", "var sum = array<u32, 3>();");
        assert!(super::validate_with(&fixed, naga::valid::Capabilities::all()).is_ok());
    }
}
