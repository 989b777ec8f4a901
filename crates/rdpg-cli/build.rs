//! Gives the `rdpg` binary an rpath to libtorch (so users need no LD_LIBRARY_PATH) and links
//! `libtorch_cuda.so` explicitly when present (otherwise the linker drops it and CUDA is never
//! available). The directory comes from rdpg-agents' build script (`links`).
fn main() {
    println!("cargo:rerun-if-env-changed=DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB");
    if let Ok(lib) = std::env::var("DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
        if std::env::var("DEP_RDPG_AGENTS_TORCH_HAS_CUDA").as_deref() == Ok("1") {
            println!("cargo:rustc-link-arg=-Wl,--no-as-needed");
            println!("cargo:rustc-link-arg=-ltorch_cuda");
        }
    }
}
