//! `nmat`: encode material maps into a `.nmat` file and back, inspect and evaluate it, or run the
//! whole chain on a bundled procedural material (`nmat demo`). See docs/ENCODING.md.
//!
//! This file parses the command line and dispatches: the arguments are declared in `args`, each
//! command is a module of `commands`, and what they share is in `common`, `reference` (the
//! `--ref` maps), `corridor` (the scene of `nmat walk`) and `gpu` (every path the `gpu` feature
//! adds, behind one seam), above the `nmat_cli` library.

mod args;
mod commands;
mod common;
mod corridor;
mod gpu;
mod reference;

use args::{Cli, Command};
use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = Cli::parse();
    nmat_cli::output::clean_up_on_signal();
    let result = match cli.command {
        Command::Encode(args) => commands::encode::run(args),
        Command::Decode(args) => commands::decode::run(args),
        Command::Transcode(args) => commands::transcode::run(args),
        Command::Index(args) => commands::index::run(args),
        Command::Build(args) => commands::build::run(args),
        Command::Info(args) => commands::info::run(args),
        Command::Pack(args) => commands::pack::pack(args),
        Command::Unpack(args) => commands::pack::unpack(args),
        Command::Eval(args) => commands::eval::run(args),
        Command::Bench(args) => commands::bench::run(args),
        Command::BenchTrain(args) => commands::bench_train::run(args),
        Command::Walk(args) => commands::walk::run(args),
        Command::Demo(args) => commands::demo::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("nmat: {}", common::message(&*e));
            ExitCode::FAILURE
        }
    }
}
