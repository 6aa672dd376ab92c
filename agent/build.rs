//! Runtime wiring for libtorch: binaries, tests and benches of this crate run
//! without `LD_LIBRARY_PATH`.
//!
//! torch-sys links against the PyTorch wheel's `torch/lib` but sets no rpath,
//! so this script finds the same directory (the same way torch-sys does: the
//! `python` on PATH when `VIRTUAL_ENV` is set, else `python3`; `LIBTORCH` or
//! `LIBTORCH_LIB` when given) and emits:
//! - `-Wl,-rpath,<torch/lib>`: the wheel's own libraries carry
//!   `$ORIGIN/../../nvidia/*/lib` rpaths, so the CUDA runtime libraries
//!   resolve from there without further entries;
//! - `-Wl,--no-as-needed -ltorch_cuda` when the wheel is a CUDA build: no
//!   symbol of libtorch_cuda is referenced directly, so the default
//!   `--as-needed` would drop it and `Cuda::is_available()` would be false.

use std::path::PathBuf;
use std::process::Command;

fn torch_lib_dir() -> Option<PathBuf> {
    if let Ok(lib) = std::env::var("LIBTORCH_LIB") {
        return Some(PathBuf::from(lib));
    }
    if std::env::var_os("LIBTORCH_USE_PYTORCH").is_none()
        && let Ok(root) = std::env::var("LIBTORCH")
    {
        return Some(PathBuf::from(root).join("lib"));
    }
    let python = if std::env::var_os("VIRTUAL_ENV").is_some() {
        "python"
    } else {
        "python3"
    };
    let output = Command::new(python)
        .arg("-c")
        .arg("import os, torch; print(os.path.join(os.path.dirname(torch.__file__), 'lib'))")
        .output()
        .ok()?;
    if !output.status.success() {
        return None;
    }
    let text = String::from_utf8(output.stdout).ok()?;
    Some(PathBuf::from(text.trim()))
}

fn main() {
    // No `rerun-if-changed=build.rs`: the tests crate runs this script too
    // (tests/Cargo.toml), and that path, relative to its package, names a file that
    // does not exist, which cargo reads as changed on every build: each `cargo test`
    // recompiled the crate and its test binaries. Cargo reruns a script whose source
    // changed anyway, and the lines below keep it from rerunning on any other file.
    for var in [
        "LIBTORCH",
        "LIBTORCH_LIB",
        "LIBTORCH_USE_PYTORCH",
        "VIRTUAL_ENV",
        "PATH",
    ] {
        println!("cargo:rerun-if-env-changed={var}");
    }
    let Some(lib) = torch_lib_dir() else {
        println!(
            "cargo:warning=agent/build.rs: could not locate torch/lib; set LD_LIBRARY_PATH to run"
        );
        return;
    };
    println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    if lib.join("libtorch_cuda.so").exists() {
        println!("cargo:rustc-link-search=native={}", lib.display());
        println!("cargo:rustc-link-arg=-Wl,--no-as-needed,-ltorch_cuda,--as-needed");
    }
}
