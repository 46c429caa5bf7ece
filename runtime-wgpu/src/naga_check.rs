//! What the unit tests ask of naga (the compiler wgpu runs) about a generated shader: parsed
//! and validated, its errors rendered against the source.

/// `source` parsed and validated with `capabilities`, or naga's error rendered against it.
pub fn validate_with(
    source: &str,
    capabilities: naga::valid::Capabilities,
) -> Result<(naga::Module, naga::valid::ModuleInfo), String> {
    let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
    let flags = naga::valid::ValidationFlags::all();
    let info = naga::valid::Validator::new(flags, capabilities)
        .validate(&module)
        .map_err(|e| e.emit_to_string(source))?;
    Ok((module, info))
}

/// [`validate_with`] every capability a device may have; panics naming `what` where naga
/// refuses `source`.
pub fn validate(what: &str, source: &str) -> naga::Module {
    validate_with(source, naga::valid::Capabilities::all())
        .unwrap_or_else(|e| panic!("{what}: {e}"))
        .0
}
