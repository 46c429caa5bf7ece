//! Integer vs float decoder on whole files: every code of every channel of every mip, the
//! statistics `tests/golden.rs` asserts on the fixtures (max |Δ| ≤ 1, |mean Δ| < 0.05 code), for
//! trained materials.
//!
//! `cargo run --release -p nmat-tests --example int_vs_float -- FILE.nmat ...`

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        eprintln!("usage: int_vs_float FILE.nmat ...");
        std::process::exit(2);
    }
    println!("| file | codes | max abs Δ | mean Δ | identical |");
    println!("|---|---:|---:|---:|---:|");
    for path in paths {
        let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let m = nmat_core::Container::parse(&bytes).unwrap_or_else(|e| panic!("{path}: {e}"));
        let a = nmat_tests::int_vs_float(&m);
        let name = std::path::Path::new(&path)
            .file_name()
            .map_or(path.clone(), |n| n.to_string_lossy().into_owned());
        println!(
            "| {name} | {} | {} | {:+.4} | {:.2} % |",
            a.count,
            a.max_abs,
            a.mean,
            100.0 * a.exact as f64 / a.count as f64
        );
    }
}
