//! Build script of bimtiles.
//!
//! Native parts are built here, one function each, so more can be added:
//! - `draco()`: our C++ shim over Debian's libdraco (no C API ships with it),
//!   found with pkg-config and linked dynamically.
//! - `proj()`: Debian's PROJ (libproj-dev, >= 9.1), found with pkg-config and linked dynamically;
//!   `src/geodesy/proj.rs` declares the few C functions used.
//! - `basisu()`: our C shim over the Basis Universal encoder that the crate basis-universal-sys
//!   compiles and links (KTX2 output, which that crate's API does not offer).
//! - `commit()`: the commit the binary is built from, for `--version` (`BIMTILES_COMMIT`).

use std::env;
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let manifest_dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    draco(&manifest_dir);
    proj();
    basisu(&manifest_dir);
    commit();
}

/// Sets `BIMTILES_COMMIT` to the short hash of the checked-out commit ("unknown" outside a git
/// checkout, e.g. a crate tarball), and reruns when the checkout moves to another commit.
fn commit() {
    let git = |args: &[&str]| -> Option<String> {
        let out = std::process::Command::new("git").args(args).output().ok()?;
        let text = String::from_utf8(out.stdout).ok()?;
        (out.status.success() && !text.trim().is_empty()).then(|| text.trim().to_string())
    };
    let hash = git(&["rev-parse", "--short=12", "HEAD"]).unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=BIMTILES_COMMIT={hash}");
    // HEAD names the branch; the branch's ref (loose or packed) names the commit.
    for dir in [
        git(&["rev-parse", "--git-dir"]),
        git(&["rev-parse", "--git-common-dir"]),
    ]
    .into_iter()
    .flatten()
    {
        let dir = PathBuf::from(dir);
        for file in ["HEAD", "packed-refs", "refs/heads"] {
            if dir.join(file).exists() {
                println!("cargo:rerun-if-changed={}", dir.join(file).display());
            }
        }
    }
}

/// Compiles `shim/basisu_shim.cc` (needs no headers: it declares the three encoder functions it
/// calls; their code is in basis-universal-sys's static library).
fn basisu(manifest_dir: &std::path::Path) {
    let source = manifest_dir.join("shim").join("basisu_shim.cc");
    println!("cargo:rerun-if-changed={}", source.display());
    cc::Build::new()
        .cpp(true)
        .std("c++11")
        .file(&source)
        .flag_if_supported("-fexceptions")
        .compile("bimtiles_basisu_shim");
}

/// Links the system PROJ library (coordinate reference systems and their transformations).
fn proj() {
    match pkg_config::Config::new()
        .atleast_version("9.1")
        .probe("proj")
    {
        Ok(_) => {}
        Err(e) => fail(&format!(
            "bimtiles needs the PROJ library (libproj-dev >= 9.1), found with pkg-config.\n\
             On Debian/Ubuntu run:\n\n    apt-get install -y libproj-dev proj-data pkg-config\n\n\
             (`make` installs it too.) pkg-config said: {e}"
        )),
    }
}

/// Compiles `shim/draco_shim.cc` and links `libdraco` (dynamic).
fn draco(manifest_dir: &std::path::Path) {
    let shim_dir = manifest_dir.join("shim");
    let source = shim_dir.join("draco_shim.cc");
    let header = shim_dir.join("draco_shim.h");
    println!("cargo:rerun-if-changed={}", source.display());
    println!("cargo:rerun-if-changed={}", header.display());
    for var in [
        "PKG_CONFIG",
        "PKG_CONFIG_PATH",
        "PKG_CONFIG_LIBDIR",
        "PKG_CONFIG_SYSROOT_DIR",
    ] {
        println!("cargo:rerun-if-env-changed={var}");
    }

    // Probe only; the link lines are printed after the shim is compiled so
    // that the static shim comes before libdraco on the linker command line.
    let lib = match pkg_config::Config::new()
        .cargo_metadata(false)
        .probe("draco")
    {
        Ok(lib) => lib,
        Err(e) => fail(&format!(
            "bimtiles needs the Draco C++ library (libdraco-dev >= 1.5), found with pkg-config, \
             and a C++17 compiler.\nOn Debian/Ubuntu run:\n\n    apt-get install -y libdraco-dev pkg-config g++\n\n\
             (`make` installs it too.) pkg-config said: {e}"
        )),
    };
    if !source.exists() {
        fail(&format!(
            "Draco shim source not found at {}",
            source.display()
        ));
    }

    let mut build = cc::Build::new();
    build
        .cpp(true)
        .std("c++17")
        .file(&source)
        .include(&shim_dir)
        .warnings(false)
        // The shim catches every exception at its C ABI boundary.
        .flag_if_supported("-fexceptions");
    for inc in &lib.include_paths {
        build.include(inc);
    }
    for (name, value) in &lib.defines {
        build.define(name, value.as_deref());
    }
    build.compile("bimtiles_draco_shim");

    for dir in &lib.link_paths {
        println!("cargo:rustc-link-search=native={}", dir.display());
    }
    for name in &lib.libs {
        println!("cargo:rustc-link-lib=dylib={name}");
    }
    if lib.libs.is_empty() {
        println!("cargo:rustc-link-lib=dylib=draco");
    }
}

/// Stops the build with a readable message (no panic backtrace).
fn fail(msg: &str) -> ! {
    eprintln!("\nerror: {msg}\n");
    std::process::exit(1);
}
