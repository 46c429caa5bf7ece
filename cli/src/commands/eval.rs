//! `nmat eval`: a .nmat file against its source maps — PSNR per map and mip, SSIM, BPPC.

use crate::args::EvalArgs;
use crate::common::{Result, chain_quality_shown, chain_quality_shown_keeping, parse};
use crate::reference::{load_reference, warn_if_decoded};
use nmat_cli::input::read_nmat;
use nmat_cli::output;
use std::time::Instant;

pub fn run(args: EvalArgs) -> Result<()> {
    let (input, reference) = (&args.input, &args.reference);
    if let Some(report) = &args.report {
        output::check_output_file("--report", report, std::slice::from_ref(input))?;
    }
    let start = Instant::now();
    let bytes = read_nmat(input)?;
    let m = parse(&bytes, input)?;
    let set = load_reference(&m, reference, args.force, args.memory.bytes())?;
    // The report shows the decodes the quality was measured on: kept, not decoded again.
    let mut decoded = Vec::new();
    let mut q = if args.report.is_some() {
        chain_quality_shown_keeping(&m, &set, &mut |_, mip| decoded.push(mip))
    } else {
        chain_quality_shown(&m, &set)
    };
    q.bppc = m.bppc_of(bytes.stored.len);
    warn_if_decoded(&q, reference);
    print!("{}", output::quality_table(&set, &q, None));
    if let Some(report) = &args.report {
        let html = nmat_cli::report::html(input, &m, bytes.stored, &set, &q, &decoded);
        output::write_atomic(report, html.as_bytes())?;
        println!("wrote {} ({} bytes)", report.display(), html.len());
    }
    println!("evaluated in {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}
