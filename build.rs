//! Build script: a digest of the sources the library is compiled from, exposed as
//! `avll._core.SOURCE_DIGEST`. A comparison of two builds (abi3 and version-specific,
//! two profiles, ...) says something about the builds only when both come from the
//! same sources; `.ci/build_identity.py` refuses to compare builds of different
//! sources, and `tests/test_build.py` fails when the extension in use was built from
//! sources other than the checkout's (a stale build). See docs/development.md, "abi3".
//!
//! The digest is FNV-1a (64 bits) over every `rust/**/*.rs`, `build.rs`, `Cargo.toml`
//! and `Cargo.lock`, in the byte order of their `/`-separated paths relative to the
//! package root, each as `path NUL content NUL`; `tests/build_helpers.py` computes the
//! same from a checkout.

use std::path::Path;

fn rust_files(root: &Path, dir: &Path, out: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            rust_files(root, &path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            if let Ok(rel) = path.strip_prefix(root) {
                let parts: Vec<String> = rel
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy().into_owned())
                    .collect();
                out.push(parts.join("/"));
            }
        }
    }
}

fn main() {
    let root = std::path::PathBuf::from(
        std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"),
    );
    let mut files = Vec::new();
    rust_files(&root, &root.join("rust"), &mut files);
    for f in ["build.rs", "Cargo.toml", "Cargo.lock"] {
        if root.join(f).is_file() {
            files.push(f.to_string());
        }
    }
    files.sort();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut feed = |bytes: &[u8]| {
        for &b in bytes {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    for f in &files {
        let content = std::fs::read(root.join(f)).expect("a listed source file is readable");
        feed(f.as_bytes());
        feed(&[0]);
        feed(&content);
        feed(&[0]);
    }
    println!("cargo:rustc-env=AVLL_SOURCE_DIGEST={h:016x}");
    println!("cargo:rerun-if-changed=rust");
    for f in ["build.rs", "Cargo.toml", "Cargo.lock"] {
        println!("cargo:rerun-if-changed={f}");
    }
}
