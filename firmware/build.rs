//! Picks the memory map per board: `memory.x` (STM32H743) or, for `--features board-qemu`,
//! `memory-qemu.x`, copied to OUT_DIR as `memory.x` for cortex-m-rt's `link.x` (and flip-link,
//! which reads the RAM region from it).
use std::path::PathBuf;
use std::{env, fs};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let map = if env::var_os("CARGO_FEATURE_BOARD_QEMU").is_some() {
        "memory-qemu.x"
    } else {
        "memory.x"
    };
    let src = manifest.join(map);
    fs::copy(&src, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("copying {}: {e}", src.display()));
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory-qemu.x");
    println!("cargo:rerun-if-changed=build.rs");
    // Identical code folding: the linker keeps one copy of functions whose code is identical
    // (monomorphised copies, the machine outliner's helpers): -740 B of .text (issue 10).
    // Folded functions share an address; nothing in the firmware compares function pointers.
    println!("cargo:rustc-link-arg-bins=--icf=all");
    if env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
