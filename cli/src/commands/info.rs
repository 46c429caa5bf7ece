//! `nmat info`: what a .nmat file holds.

use crate::args::InfoArgs;
use crate::common::{Result, parse};
use nmat_cli::input::read_nmat;
use nmat_cli::output;

pub fn run(args: InfoArgs) -> Result<()> {
    let bytes = read_nmat(&args.input)?;
    let m = parse(&bytes, &args.input)?;
    print!("{}", output::describe(&args.input, &m, bytes.stored));
    Ok(())
}
