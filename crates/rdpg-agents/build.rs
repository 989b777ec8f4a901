//! Build script: finds the libtorch library directory and
//!
//! * re-exports it to direct dependents (`links = "rdpg_agents_torch"` makes it
//!   `DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB` in their build scripts), so that the binary crate can
//!   emit its own rpath;
//! * gives this crate's own executables (unit-test harness, integration tests, benches,
//!   examples) an rpath to it and links
//!   `libtorch_cuda.so` with `--no-as-needed` (otherwise the linker drops it and
//!   `tch::Cuda::is_available()` is false even on a GPU machine).
//!
//! Link arguments emitted here apply to this package's targets only; they do not propagate to
//! dependents.

use std::path::PathBuf;
use std::process::Command;

/// The libtorch `lib` directory: torch-sys's export, else the `python3` on `PATH`.
fn libtorch_lib_dir() -> Option<PathBuf> {
    if let Ok(dir) = std::env::var("DEP_TCH_LIBTORCH_LIB") {
        return Some(PathBuf::from(dir));
    }
    let out = Command::new("python3")
        .args([
            "-c",
            "import torch, os; print(os.path.join(os.path.dirname(torch.__file__), 'lib'))",
        ])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let dir = String::from_utf8(out.stdout).ok()?.trim().to_owned();
    (!dir.is_empty()).then(|| PathBuf::from(dir))
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=DEP_TCH_LIBTORCH_LIB");
    let Some(lib) = libtorch_lib_dir() else {
        println!("cargo:warning=rdpg-agents: libtorch lib dir not found; no rpath emitted");
        return;
    };
    let lib = lib.display().to_string();
    println!("cargo:libtorch_lib={lib}");
    let has_cuda = PathBuf::from(&lib).join("libtorch_cuda.so").exists();
    println!("cargo:has_cuda={}", u8::from(has_cuda));
    // `rustc-link-arg` (unlike `-tests`/`-benches`) is accepted whatever targets exist, and
    // applies to every executable of this package: the unit-test harness, integration tests,
    // benches and examples. It never reaches dependents.
    println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
    if has_cuda {
        println!("cargo:rustc-link-arg=-Wl,--no-as-needed");
        println!("cargo:rustc-link-arg=-ltorch_cuda");
    }
}
