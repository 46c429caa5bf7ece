//! Gives the shared library a SONAME on Linux, so programs linked against it record the ABI they
//! were built for: `libnmat.so.MAJOR` from 1.0 on, `libnmat.so.0.MINOR` before (a 0.x minor
//! release may change the ABI, as Cargo's version rules allow). `make -C bindings-c install`
//! installs the file under that name plus `libnmat.so.MAJOR.MINOR.PATCH` and the `libnmat.so`
//! link. Android loads libraries by their plain file name, so it gets none.
fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    if os != "linux" {
        return;
    }
    let major = std::env::var("CARGO_PKG_VERSION_MAJOR").expect("cargo sets the version");
    let minor = std::env::var("CARGO_PKG_VERSION_MINOR").expect("cargo sets the version");
    let soname =
        if major == "0" { format!("libnmat.so.0.{minor}") } else { format!("libnmat.so.{major}") };
    println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,{soname}");
}
