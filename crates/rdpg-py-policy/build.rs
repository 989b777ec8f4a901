//! Gives the extension module an rpath to the libtorch it was built against (the venv's
//! torch), like the `rdpg` binary; `rdpg.Policy` imports torch first, which loads it.
fn main() {
    println!("cargo:rerun-if-env-changed=DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB");
    if let Ok(lib) = std::env::var("DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
    }
}
