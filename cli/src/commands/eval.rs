//! `nmat eval`: .nmat files against their source maps — PSNR per map and mip, SSIM, BPPC — and
//! with `--report`, one HTML page to look at them.

use crate::args::EvalArgs;
use crate::common::{Result, chain_quality_shown, chain_quality_shown_keeping, parse};
use crate::reference::{load_reference, warn_if_decoded};
use nmat_cli::input::read_nmat;
use nmat_cli::output;
use nmat_cli::report::{self, PlotPoint};
use std::time::Instant;

pub fn run(args: EvalArgs) -> Result<()> {
    let reference = &args.reference;
    if let Some(path) = &args.report {
        output::check_output_file("--report", path, &args.inputs)?;
    }
    // Read before any decoding: a bad anchors file is an error before the work.
    let material = report::material_name(reference);
    let anchors = match &args.anchors {
        Some(path) => report::read_anchors(path, &material)?,
        None => Vec::new(),
    };
    let start = Instant::now();
    let (mut sections, mut points) = (Vec::new(), Vec::new());
    for input in &args.inputs {
        if args.inputs.len() > 1 {
            println!("== {} ==", input.display());
        }
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
        if args.report.is_some() {
            sections.push(report::section(input, &m, bytes.stored, &set, &q, &decoded));
            points.push(PlotPoint::of_file(input, &m, &q));
        }
    }
    if let Some(path) = &args.report {
        // One file alone has nothing to be compared with: no plot then.
        let plot = (points.len() + anchors.len() > 1).then(|| {
            points.extend(anchors);
            report::plot("Rate and quality", &points)
        });
        let html = report::page(&material, plot.as_deref(), &sections);
        output::write_atomic(path, html.as_bytes())?;
        println!("wrote {} ({} bytes)", path.display(), html.len());
    }
    println!("evaluated in {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}
