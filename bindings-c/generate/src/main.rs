//! `cargo run -p nmat-header` regenerates `bindings-c/include/nmat.h`;
//! `cargo run -p nmat-header -- --check` fails if the committed header differs by a byte (CI).

use std::path::PathBuf;
use std::process::ExitCode;

fn main() -> ExitCode {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let crate_dir = root.join("ffi");
    let header = root.join("bindings-c/include/nmat.h");
    let config = match cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("ffi/cbindgen.toml: {e}");
            return ExitCode::FAILURE;
        }
    };
    let bindings =
        match cbindgen::Builder::new().with_crate(&crate_dir).with_config(config).generate() {
            Ok(b) => b,
            Err(e) => {
                eprintln!("cbindgen: {e}");
                return ExitCode::FAILURE;
            }
        };
    let mut fresh = Vec::new();
    bindings.write(&mut fresh);
    if std::env::args().any(|a| a == "--check") {
        let committed = std::fs::read(&header).unwrap_or_default();
        if committed != fresh {
            eprintln!(
                "{} is out of date: run `cargo run -p nmat-header` and commit it",
                header.display()
            );
            return ExitCode::FAILURE;
        }
        println!("{} is up to date", header.display());
        return ExitCode::SUCCESS;
    }
    if let Err(e) = std::fs::write(&header, &fresh) {
        eprintln!("{}: {e}", header.display());
        return ExitCode::FAILURE;
    }
    println!("wrote {}", header.display());
    ExitCode::SUCCESS
}
