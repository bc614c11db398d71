//! Link setup for the firmware binary: provides the workspace's `memory.x` to cortex-m-rt's
//! `link.x` and adds the linker scripts of cortex-m-rt and defmt.
//!
//! The link arguments are given to the binary only (`rustc-link-arg-bins`), not through
//! `.cargo/config.toml` rustflags, because the core is also built for the same target as a
//! plain library, which must not be linked with these scripts.

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let manifest_dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR")?);
    // The memory map is shared by the whole workspace: it sits at the workspace root, one
    // level above this package.
    let memory_x = manifest_dir
        .parent()
        .ok_or("firmware package has no parent directory")?
        .join("memory.x");
    let out_dir = PathBuf::from(env::var("OUT_DIR")?);

    // cortex-m-rt's link.x does `INCLUDE memory.x`, which the linker looks up in the search
    // path: put a copy in OUT_DIR and add OUT_DIR to that path.
    fs::copy(&memory_x, out_dir.join("memory.x"))
        .map_err(|e| format!("cannot copy {}: {e}", memory_x.display()))?;
    println!("cargo:rustc-link-search={}", out_dir.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");

    // Keep sections aligned to their load address without page padding (cortex-m-quickstart).
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    Ok(())
}
