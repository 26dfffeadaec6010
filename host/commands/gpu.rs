//! `dustsph gpu`: how the GPU kernels were built, whether a device is usable; optionally the
//! embedded PTX written to a file (for `ptxas`).

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct GpuArgs {
    /// Write the embedded PTX to this file
    #[arg(long, value_name = "FILE")]
    write_ptx: Option<PathBuf>,
    /// Replace FILE if it exists
    #[arg(long)]
    force: bool,
}

pub fn execute(a: GpuArgs) -> u8 {
    let GpuArgs { write_ptx, force } = a;
    if let Some(f) = &write_ptx {
        if f.exists() && !force {
            eprintln!(
                "error: {} exists: not replaced (--force replaces it)",
                f.display()
            );
            return 2;
        }
    }
    use crate::launch;
    use std::io::Write as _;
    // A reader that closes the pipe early (`dustsph gpu | head -1`) is not an error.
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "kernels: {} ({} bytes of PTX, {} entry points)",
        launch::PTX_NOTE,
        launch::PTX.len(),
        launch::PTX.matches(".entry ").count()
    );
    let _ = match launch::register_cap() {
        Ok(Some(n)) => writeln!(
            out,
            "registers: at most {n} a thread when loaded (DUSTSPH_PTX_MAXNREG=N or off changes it)"
        ),
        Ok(None) => writeln!(out, "registers: uncapped (DUSTSPH_PTX_MAXNREG=off)"),
        Err(e) => writeln!(out, "registers: {e}"),
    };
    let _ = match launch::probe() {
        Ok(name) => writeln!(out, "device: {name}"),
        Err(why) => writeln!(out, "device: none ({why})"),
    };
    if let Some(f) = write_ptx {
        if launch::PTX.is_empty() {
            eprintln!(
                "error: this binary has no PTX to write ({})",
                launch::PTX_NOTE
            );
            return 1;
        }
        if let Err(e) = std::fs::write(&f, launch::PTX) {
            eprintln!("error: {}: {e}", f.display());
            return 1;
        }
        let _ = writeln!(out, "wrote {}", f.display());
    }
    0
}
