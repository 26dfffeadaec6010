//! Build script: records the source revision, and compiles the GPU kernels (the `device/`
//! crate, the same source the CPU path uses) to PTX with rustc's NVPTX backend on the nightly
//! toolchain, for the binary to embed. Without nightly (or its rust-src), the host still builds:
//! the embedded PTX is then empty and `--device cuda` says the GPU path was not built, and why.
use std::path::{Path, PathBuf};
use std::process::Command;

/// The virtual architecture the PTX targets: PTX 7.0, JIT-compiled by the driver for sm_80
/// (A100), sm_89 and sm_90 (H100/H200) alike.
const PTX_ARCH: &str = "sm_80";

fn main() {
    let git = Command::new("git")
        .args(["describe", "--always", "--dirty", "--abbrev=12"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=DUSTSPH_GIT={git}");
    println!("cargo:rerun-if-changed=.git/HEAD");
    println!("cargo:rerun-if-changed=.git/index");

    println!("cargo:rerun-if-changed=device/src");
    println!("cargo:rerun-if-changed=device/Cargo.toml");
    println!("cargo:rerun-if-env-changed=DUSTSPH_NO_PTX");
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    let (ptx, note) = if std::env::var_os("DUSTSPH_NO_PTX").is_some() {
        (
            String::new(),
            "not built: DUSTSPH_NO_PTX was set".to_string(),
        )
    } else {
        match build_ptx(&out) {
            Ok(p) => (p, format!("built for {PTX_ARCH} by rustc's NVPTX backend")),
            Err(e) => {
                println!("cargo:warning=GPU kernels not built ({e}); the CPU path is unaffected");
                (String::new(), format!("not built: {e}"))
            }
        }
    };
    std::fs::write(out.join("dustsph.ptx"), ptx).expect("write PTX into OUT_DIR");
    println!("cargo:rustc-env=DUSTSPH_PTX_NOTE={note}");
    println!("cargo:rustc-env=DUSTSPH_PTX_ARCH={PTX_ARCH}");
}

/// The rustup `cargo` proxy (so that `RUSTUP_TOOLCHAIN=nightly` selects nightly).
fn cargo_proxy() -> PathBuf {
    let home = std::env::var_os("CARGO_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cargo")));
    home.map(|h| h.join("bin").join("cargo"))
        .filter(|p| p.exists())
        .unwrap_or_else(|| PathBuf::from("cargo"))
}

fn build_ptx(out: &Path) -> Result<String, String> {
    let manifest = Path::new(&std::env::var("CARGO_MANIFEST_DIR").unwrap()).join("device");
    let target_dir = out.join("ptx-build");
    let deps = target_dir.join("nvptx64-nvidia-cuda/release/deps");
    let mut cmd = Command::new(cargo_proxy());
    // The outer cargo's settings must not leak into the nightly device build.
    for v in [
        "RUSTC",
        "RUSTC_WRAPPER",
        "RUSTC_WORKSPACE_WRAPPER",
        "RUSTFLAGS",
        "CARGO_ENCODED_RUSTFLAGS",
        "CARGO_TARGET_DIR",
        "CARGO_BUILD_TARGET",
        "CARGO_MAKEFLAGS",
        "CARGO",
        "RUSTDOC",
    ] {
        cmd.env_remove(v);
    }
    cmd.env("RUSTUP_TOOLCHAIN", "nightly")
        // Local copies of cross-crate functions (libm, core) so the PTX has no external calls;
        // panics become a trap instead of a call into core's formatting machinery.
        .env(
            "RUSTFLAGS",
            "-Zcross-crate-inline-threshold=always -Zunstable-options -Cpanic=immediate-abort",
        )
        .current_dir(&manifest)
        .args([
            "rustc",
            "--release",
            "--target",
            "nvptx64-nvidia-cuda",
            "-Zbuild-std=core",
            "--target-dir",
        ])
        .arg(&target_dir)
        .args([
            "--",
            "--emit=asm",
            "-Ccodegen-units=1",
            "-Cdebuginfo=0",
            &format!("-Ctarget-cpu={PTX_ARCH}"),
        ]);
    let o = cmd
        .output()
        .map_err(|e| format!("cannot run {}: {e}", cargo_proxy().display()))?;
    if !o.status.success() {
        let err = String::from_utf8_lossy(&o.stderr);
        let first = err
            .lines()
            .find(|l| l.contains("error"))
            .unwrap_or("nightly build failed");
        return Err(format!(
            "nightly NVPTX build failed: {first} (needs `rustup toolchain install nightly` and \
             `rustup component add rust-src --toolchain nightly`)"
        ));
    }
    // The newest dustsph_device PTX: a build that found the crate fresh re-emits nothing and
    // leaves the last output in place.
    let s = std::fs::read_dir(&deps)
        .map_err(|e| format!("no PTX output in {}: {e}", deps.display()))?
        .flatten()
        .filter(|e| {
            let p = e.path();
            p.extension().is_some_and(|x| x == "s")
                && p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("dustsph_device"))
        })
        .max_by_key(|e| e.metadata().and_then(|m| m.modified()).ok())
        .map(|e| e.path())
        .ok_or("the nightly build wrote no dustsph_device PTX")?;
    let ptx = std::fs::read_to_string(&s).map_err(|e| format!("{}: {e}", s.display()))?;
    if ptx.contains(".extern") {
        return Err("the PTX has unresolved .extern symbols".into());
    }
    Ok(ptx)
}
