//! The command line: `dustsph stiffness [--full] [--out FILE [--force]]`.
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct StiffnessArgs {
    /// The full grid (default: the reduced CI grid)
    #[arg(long)]
    full: bool,
    /// Write the Markdown table to this file (e.g. docs/stiffness.md)
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace an existing --out file
    #[arg(long)]
    force: bool,
}

pub fn execute(a: StiffnessArgs) -> u8 {
    let StiffnessArgs { full, out, force } = a;
    if let Some(o) = &out {
        if o.exists() && !force {
            eprintln!("error: {} exists; give --force to replace it", o.display());
            return 2;
        }
        // Where the report goes must be writable before the matrix runs (minutes with --full).
        let dir = match o.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let probe = dir.join(format!(".dustsph-write-check-{}.tmp", std::process::id()));
        if o.is_dir() {
            eprintln!(
                "error: {} is a directory; --out names the report file",
                o.display()
            );
            return 2;
        }
        if let Err(e) = std::fs::write(&probe, b"") {
            eprintln!(
                "error: {}: cannot write the report there ({e})",
                o.display()
            );
            return 2;
        }
        let _ = std::fs::remove_file(&probe);
    }
    let reports = crate::commands::stiffness::run(full, |r| {
        eprintln!(
            "{:<6} {} — {}: {} steps (explicit would need {:.0}), momentum drift {:.1e}",
            if r.passed() { "pass" } else { "FAIL" },
            r.group,
            r.name,
            r.steps,
            r.explicit_steps,
            r.momentum_drift
        );
        for f in &r.failures {
            eprintln!("       {f}");
        }
    });
    let failed = reports.iter().filter(|r| !r.passed()).count();
    if let Some(o) = &out {
        let command = format!(
            "dustsph stiffness{} --out {} --force",
            if full { " --full" } else { "" },
            o.display()
        );
        let md = crate::commands::stiffness::markdown(&reports, full, &command);
        if let Err(e) = crate::io::write_bytes_atomic(o, md.as_bytes()) {
            eprintln!("error: {e}");
            return 1;
        }
        println!("wrote {}", o.display());
    }
    println!("{} of {} cases pass", reports.len() - failed, reports.len());
    if failed > 0 {
        1
    } else {
        0
    }
}
