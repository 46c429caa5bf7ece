//! `intel_tex_2`'s prebuilt ISPC kernels are C++ objects: link the C++ runtime they need.
fn main() {
    println!("cargo:rustc-link-lib=dylib=stdc++");
}
