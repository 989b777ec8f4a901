//! Gives the `rdpg` binary an rpath to libtorch (so users need no LD_LIBRARY_PATH) and links
//! `libtorch_cuda.so` explicitly when present (otherwise the linker drops it and CUDA is never
//! available). The directory comes from rdpg-agents' build script (`links`). Also records the
//! git commit the binary was built from (`RDPG_GIT_COMMIT`: the hash, `+dirty` when tracked
//! files differed from it, `unknown` outside a git checkout), which every run directory keeps.
use std::process::Command;

fn main() {
    println!("cargo:rerun-if-env-changed=DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB");
    if let Ok(lib) = std::env::var("DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
        if std::env::var("DEP_RDPG_AGENTS_TORCH_HAS_CUDA").as_deref() == Ok("1") {
            println!("cargo:rustc-link-arg=-Wl,--no-as-needed");
            println!("cargo:rustc-link-arg=-ltorch_cuda");
        }
    }
    let git = |args: &[&str]| {
        Command::new("git")
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    let commit = match git(&["rev-parse", "HEAD"]) {
        Some(hash) => {
            let dirty = git(&["status", "--porcelain", "--untracked-files=no"])
                .is_some_and(|s| !s.is_empty());
            if dirty {
                format!("{hash}+dirty")
            } else {
                hash
            }
        }
        None => "unknown".into(),
    };
    println!("cargo:rustc-env=RDPG_GIT_COMMIT={commit}");
    if let Some(dir) = git(&["rev-parse", "--absolute-git-dir"]) {
        println!("cargo:rerun-if-changed={dir}/HEAD");
        println!("cargo:rerun-if-changed={dir}/index");
    }
}
