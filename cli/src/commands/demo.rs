//! `nmat demo`: encode, decode and evaluate a bundled procedural material, and print a report.

use crate::args::DemoArgs;
use crate::common::{Result, encode_with_progress, parse, profile_named, threads, train_options};
use nmat_cli::output;
use nmat_core::AddressMode;
use nmat_encode::EncodeOptions;
use std::time::Instant;

/// Steps of `nmat demo` when not given: its 256² material needs fewer than a 1024² one.
const DEMO_STEPS: usize = 3000;

pub fn run(args: DemoArgs) -> Result<()> {
    let (out, train, profile) = (&args.out, &args.train, args.profile.as_str());
    threads(train.threads)?;
    let profile = profile_named(profile)?;
    let set = nmat_encode::demo::bricks(256);
    let source = out.join("source");
    output::write_source_maps(&set, &source)?;
    println!(
        "demo: a procedural 256×256 brick material (albedo RGB, normal XYZ, roughness, height; {} mips), profile {}",
        set.mips.len(),
        profile.name()
    );
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let start = Instant::now();
    let options = EncodeOptions {
        profile,
        train: train_options(train, DEMO_STEPS)?,
        address_mode: AddressMode::Wrap,
        storage: Default::default(),
        memory_factor: nmat_encode::DEFAULT_MEMORY_FACTOR,
        legacy_lod: false,
        layout: Default::default(),
        polish_sweeps: None,
    };
    let encoded = encode_with_progress(&set, &options)?;
    let path = out.join("demo.nmat");
    output::write_atomic(&path, encoded.file())?;
    println!(
        "encoded in {:.1} s → {} ({} bytes)",
        start.elapsed().as_secs_f64(),
        path.display(),
        encoded.file().len()
    );
    let m = parse(&encoded.bytes, &path)?;
    let plan = output::DecodePlan::new(&m, &[0], false)?;
    let decoded = out.join("decoded");
    std::fs::create_dir_all(&decoded).map_err(|e| format!("{}: {e}", decoded.display()))?;
    let with = output::DecodeWith::default();
    let written = output::write_maps(&m, &plan, &decoded, with, &mut |_| {})?;
    println!(
        "source maps in {}, {} decoded maps in {}",
        source.display(),
        written.len(),
        decoded.display()
    );
    print!(
        "{}",
        output::quality_table(&set, &encoded.quality, Some(&format!("profile {}", profile.name())))
    );
    // This binary as the user can type it from here (`target/release/nmat` after `cargo run`).
    let nmat = match (std::env::current_exe(), std::env::current_dir()) {
        (Ok(exe), Ok(here)) => exe.strip_prefix(&here).unwrap_or(&exe).display().to_string(),
        _ => "nmat".to_string(),
    };
    println!(
        "\nnext: measure it against the source maps, and the decode speed and accuracy knobs:\n  \
         {nmat} eval {p} --ref {s}\n  {nmat} bench {p} --ref {s}",
        p = path.display(),
        s = source.display()
    );
    Ok(())
}
