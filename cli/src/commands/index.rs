//! `nmat index`: a baseline JPEG file → a .nmat material, its coded data kept as it is.

use crate::args::IndexArgs;
use crate::common::{Result, parse};
use nmat_cli::output;
use nmat_encode::Storage;

pub fn run(args: IndexArgs) -> Result<()> {
    let (input, out, max_memory) = (&args.input, &args.output, args.memory.bytes());
    output::check_output(out, &[input.to_path_buf()])?;
    // A .nmat file holds at most 4 GiB (docs/FORMAT.md §2), so a larger JPEG cannot be indexed.
    let limit = max_memory.min(u64::from(u32::MAX));
    let file = nmat_encode::input::read_regular(input, limit)?;
    let indexed =
        nmat_encode::jpeg::index_jpeg(&file).map_err(|e| format!("{}: {e}", input.display()))?;
    // `nmat decode` writes the map back as STEM.png.
    let stem = input.file_stem().map_or("image".into(), |s| s.to_string_lossy());
    let bytes = nmat_encode::jpeg::material_from_jpeg(&indexed, &format!("{stem}.png"))
        .to_bytes()
        .map_err(|e| format!("{}: cannot index: {e}", input.display()))?;
    let storage = if args.fixed_rate { Storage::FixedRate } else { Storage::Packed };
    let packed = nmat_encode::packed_form(&bytes, storage)?;
    let file = packed.as_deref().unwrap_or(&bytes);
    output::write_atomic(out, file)?;
    let m = parse(&bytes, out)?;
    let (extra, coded) = m.jpeg().map_or((0, 0), |j| j.overhead_bits());
    let texels = f64::from(indexed.width) * f64::from(indexed.height);
    let kept = if packed.is_some() { "rebuilt when opened, in memory" } else { "in the file" };
    println!(
        "{}: {}×{} {}, {} bytes ({} bytes of JPEG data; index and DC values {kept}: {:.3} bits \
         per pixel)",
        out.display(),
        indexed.width,
        indexed.height,
        if indexed.map.channel_count == 3 {
            format!("YCbCr {}×{} luma per chroma sample", indexed.map.luma_h, indexed.map.luma_v)
        } else {
            "gray".to_string()
        },
        file.len(),
        coded / 8,
        extra as f64 / texels
    );
    Ok(())
}
