//! Embeds the libtorch search path in the `ciflow` binary and its tests, so they run from
//! any shell without `LD_LIBRARY_PATH`.

fn main() {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    if let Ok(libtorch) = std::env::var("LIBTORCH") {
        // DT_RPATH (not RUNPATH) also serves libtorch's own dependencies (libcudart).
        println!("cargo:rustc-link-arg=-Wl,--disable-new-dtags");
        for dir in ["lib", "cuda-lib"] {
            println!("cargo:rustc-link-arg=-Wl,-rpath,{libtorch}/{dir}");
        }
    }
}
