//! `nmat decode`: the maps of a .nmat file back as images, all or nothing.

use crate::args::DecodeArgs;
use crate::common::{Result, mib, parse, refuse_existing, with_decode_progress};
use nmat_cli::input::read_nmat;
use nmat_cli::output;
use nmat_encode::texset;
use std::time::Instant;

pub fn run(args: DecodeArgs) -> Result<()> {
    let bytes = read_nmat(&args.input)?;
    let m = parse(&bytes, &args.input)?;
    let mips: Vec<u32> = if args.mip == "all" {
        (0..m.mip_count()).collect()
    } else {
        let mip: u32 = args
            .mip
            .parse()
            .map_err(|_| format!("--mip {}: expected a number or \"all\"", args.mip))?;
        if mip >= m.mip_count() {
            return Err(
                format!("--mip {mip}: the material has mips 0..{}", m.mip_count() - 1).into()
            );
        }
        vec![mip]
    };
    let plan = output::DecodePlan::new(&m, &mips, args.png)
        .map_err(|e| format!("{}: {e}", args.input.display()))?;
    let names = plan.file_names();
    if !args.force {
        refuse_existing(&args.output, &names)?;
    }
    let (need, allowed) = (plan.memory(&m), args.max_memory.unwrap_or(texset::DEFAULT_MAX_MEMORY));
    if need > allowed {
        return Err(format!(
            "{}: writing these maps needs about {:.1} MiB, more than the {:.1} MiB allowed; \
             nothing was written. Raise the limit with --max-memory or decode one mip at a time \
             (--mip)",
            args.input.display(),
            mib(need),
            mib(allowed)
        )
        .into());
    }
    let start = Instant::now();
    let float = args.float;
    let written = with_decode_progress("decode", plan.cost(&m), |progress| {
        output::write_all_or_nothing(&args.output, |dir| {
            if args.gpu {
                crate::gpu::decode_maps(&m, &plan, dir, progress, args.kernel_choices.as_deref())
            } else {
                let with = output::DecodeWith { float, batch: None };
                output::write_maps(&m, &plan, dir, with, progress)
            }
        })
    })?;
    for w in &written {
        println!("wrote {}", w.display());
    }
    println!("decoded {} files in {:.1} s", written.len(), start.elapsed().as_secs_f64());
    Ok(())
}
