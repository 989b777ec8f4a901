//! Builds Box2D 2.3 from sources fetched at setup (never committed) plus rdpg's C shim.
//!
//! Source directory: `$RDPG_BOX2D_DIR` if set, else `<workspace>/.deps/box2d-py-2.3.8`
//! (what `scripts/setup/fetch_box2d.sh` fetches: pybox2d's own Box2D 2.3.0, the engine Gymnasium runs
//! on). The directory must contain `Box2D/Box2D.h`. A stock Box2D 2.3.1 tree is accepted too;
//! it is detected by its `b2Sweep::Advance` and reported through `rdpg_box2d::FLAVOR` so that
//! the parity tests can say so and fall back to a tolerance.
//!
//! Compiler flags are fixed (-O3, no fast-math, no FMA contraction, baseline x86-64) whatever
//! the cargo profile, because bit-for-bit parity with Gymnasium depends on them.

use std::env;
use std::fs;
use std::path::{Path, PathBuf};

fn main() {
    println!("cargo:rerun-if-env-changed=RDPG_BOX2D_DIR");
    println!("cargo:rerun-if-changed=cpp/shim.cpp");
    let manifest = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap());
    let src_root = env::var_os("RDPG_BOX2D_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| manifest.join("../../.deps/box2d-py-2.3.8"));
    let header = src_root.join("Box2D/Box2D.h");
    if !header.is_file() {
        panic!(
            "\n\nBox2D 2.3 sources not found: {} does not exist.\n\
             Run `scripts/setup/fetch_box2d.sh` (or `scripts/setup.sh`) to fetch pybox2d's Box2D 2.3.0 \
             from PyPI (box2d-py==2.3.8), or point RDPG_BOX2D_DIR at a directory holding \
             Box2D/Box2D.h.\n\n",
            header.display()
        );
    }
    println!(
        "cargo:rerun-if-changed={}",
        src_root.join("Box2D").display()
    );

    // Copy the tree into OUT_DIR so that it can be patched without touching the fetched copy.
    let out = PathBuf::from(env::var("OUT_DIR").unwrap());
    let tree = out.join("box2d-src");
    let _ = fs::remove_dir_all(&tree);
    let mut sources = Vec::new();
    copy_tree(&src_root.join("Box2D"), &tree.join("Box2D"), &mut sources);

    // pybox2d's b2Settings.h turns asserts into Python exceptions; build standalone instead.
    let settings = tree.join("Box2D/Common/b2Settings.h");
    let text = fs::read_to_string(&settings).expect("read b2Settings.h");
    fs::write(&settings, text.replace("#define USE_EXCEPTIONS", "")).expect("patch b2Settings.h");

    let math = fs::read_to_string(tree.join("Box2D/Common/b2Math.h")).expect("read b2Math.h");
    let flavor = if math.contains("c0 += beta") {
        "box2d-2.3.1-stock"
    } else if math.contains("c0 = (1.0f - beta) * c0 + beta * c") {
        "pybox2d-2.3.0"
    } else {
        "unknown"
    };
    println!("cargo:rustc-env=RDPG_BOX2D_FLAVOR={flavor}");

    let mut build = cc::Build::new();
    build
        .cpp(true)
        .include(&tree)
        .opt_level(3)
        .debug(false)
        .flag_if_supported("-std=c++11")
        .flag_if_supported("-ffp-contract=off")
        .flag_if_supported("-fno-fast-math")
        .flag_if_supported("-fno-math-errno")
        .warnings(false)
        .define("NDEBUG", None)
        .files(&sources)
        .file(manifest.join("cpp/shim.cpp"));
    build.compile("rdpg_box2d");
}

fn copy_tree(from: &Path, to: &Path, sources: &mut Vec<PathBuf>) {
    fs::create_dir_all(to).expect("create dir in OUT_DIR");
    let mut entries: Vec<_> = fs::read_dir(from)
        .unwrap_or_else(|e| panic!("read {}: {e}", from.display()))
        .map(|e| e.expect("dir entry").path())
        .collect();
    entries.sort();
    for path in entries {
        let name = path.file_name().unwrap();
        let target = to.join(name);
        if path.is_dir() {
            // Testbed / HelloWorld folders of stock trees are not part of the library.
            if name == "Testbed" || name == "HelloWorld" || name == "Build" {
                continue;
            }
            copy_tree(&path, &target, sources);
        } else if matches!(
            path.extension().and_then(|e| e.to_str()),
            Some("h") | Some("cpp")
        ) {
            fs::copy(&path, &target).expect("copy source");
            if target.extension().is_some_and(|e| e == "cpp") {
                sources.push(target);
            }
        }
    }
}
