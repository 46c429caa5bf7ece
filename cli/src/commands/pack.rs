//! `nmat pack` and `nmat unpack`: a file packed (latents entropy-coded, JPEG streams without
//! their index) or fixed-rate (docs/FORMAT.md §12), losslessly both ways.

use crate::args::PackArgs;
use crate::common::{Result, parse};
use nmat_cli::input::read_nmat;
use nmat_cli::output;

/// Packs `args.input` into `args.output`.
pub fn pack(args: PackArgs) -> Result<()> {
    let (fixed, written) = convert(&args, |fixed| {
        nmat_core::pack(fixed).map_err(|e| format!("{}: {e}", args.input.display()).into())
    })?;
    println!(
        "wrote {} ({written} bytes, {:.3} of the {fixed} bytes fixed-rate)",
        args.output.display(),
        written as f64 / fixed as f64,
    );
    Ok(())
}

/// Writes the fixed-rate form of `args.input` into `args.output`.
pub fn unpack(args: PackArgs) -> Result<()> {
    let (_, written) = convert(&args, |fixed| Ok(fixed.to_vec()))?;
    println!("wrote {} ({written} bytes, fixed-rate)", args.output.display());
    Ok(())
}

/// Reads and checks the input (a packed one is unpacked and parsed), makes the output bytes from
/// its fixed-rate form and writes them atomically; returns the fixed-rate and the output sizes.
fn convert(args: &PackArgs, make: impl Fn(&[u8]) -> Result<Vec<u8>>) -> Result<(usize, usize)> {
    output::check_output(&args.output, std::slice::from_ref(&args.input))?;
    let fixed = read_nmat(&args.input)?;
    parse(&fixed, &args.input)?;
    let bytes = make(&fixed)?;
    output::write_atomic(&args.output, &bytes)?;
    Ok((fixed.len(), bytes.len()))
}
