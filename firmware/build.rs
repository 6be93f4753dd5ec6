//! Picks the memory map per board. The real board's map is `memory.x` at the workspace root,
//! which cortex-m-rt's `link.x` includes (the linker finds it in its working directory, the
//! workspace root). For `--features board-qemu` we pass the `_board_*` symbols of
//! `memory-qemu.x` to the linker, and `memory.x` takes them instead of the STM32H743 values.
use std::path::PathBuf;
use std::{env, fs};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    // Also put memory.x on the search path, for builds whose linker runs elsewhere.
    let real = manifest.join("../memory.x");
    fs::copy(&real, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("copying {}: {e}", real.display()));
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", real.display());
    println!("cargo:rerun-if-changed=memory-qemu.x");
    println!("cargo:rerun-if-changed=build.rs");
    if env::var_os("CARGO_FEATURE_BOARD_QEMU").is_some() {
        // `name = value;` lines, passed as --defsym: symbols assigned in a linker script are not
        // yet DEFINED() when the linker evaluates MEMORY, command-line symbols are.
        let qemu = manifest.join("memory-qemu.x");
        let text =
            fs::read_to_string(&qemu).unwrap_or_else(|e| panic!("reading {}: {e}", qemu.display()));
        let mut n = 0;
        for line in text
            .lines()
            .map(str::trim)
            .filter(|l| l.starts_with("_board_"))
        {
            let (name, value) = line
                .trim_end_matches(';')
                .split_once('=')
                .expect("name = value;");
            println!(
                "cargo:rustc-link-arg-bins=--defsym={}={}",
                name.trim(),
                value.trim()
            );
            n += 1;
        }
        assert_eq!(n, 4, "memory-qemu.x must define the four _board_* symbols");
    }
    if env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
