//! `dustsph study`: its options and its execution.
use super::*;

#[derive(clap::Args)]
pub struct StudyArgs {
    /// Study file (TOML), e.g. configs/studies/dustywave_n1.toml
    study: PathBuf,
    /// Output directory (default: output/studies/<study name>)
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write into a non-empty output directory (replaces only the study's own files)
    #[arg(long)]
    force: bool,
    /// No line per point
    #[arg(long, short)]
    quiet: bool,
    /// Validate the study and list its points; run nothing, write nothing
    #[arg(long)]
    dry_run: bool,
}

pub fn execute(a: StudyArgs) -> u8 {
    let StudyArgs {
        study,
        out,
        force,
        quiet,
        dry_run,
    } = a;
    let st = match crate::commands::study::load(&study) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return 2;
        }
    };
    if dry_run {
        let all: Vec<usize> = (0..st.axes.len()).collect();
        for (i, p) in st.points.iter().enumerate() {
            println!("{:>4}  {}", i + 1, st.describe(p, &all, false));
        }
        return 0;
    }
    let out = out.unwrap_or_else(|| PathBuf::from("output/studies").join(&st.cfg.name));
    let command = format!(
        "dustsph study {} --out {} --force",
        study.display(),
        out.display()
    );
    if !quiet {
        eprintln!(
            "dustsph: study {} ({} points) → {}",
            study.display(),
            st.points.len(),
            out.display()
        );
    }
    match crate::commands::study::run(&st, &out, force, quiet, &command) {
        Ok((results, files)) => {
            for f in &files {
                println!("wrote {}", f.display());
            }
            let failed = results
                .iter()
                .filter(|r| matches!(r.status, crate::commands::study::Status::Failed(_)))
                .count();
            if failed > 0 {
                eprintln!("error: {failed} point(s) failed (see results.md)");
                return 1;
            }
            // Every point skipped (over max_steps): the tables and plots hold no measurement.
            if !results.is_empty()
                && results
                    .iter()
                    .all(|r| matches!(r.status, crate::commands::study::Status::Skipped(_)))
            {
                eprintln!(
                    "error: every point was skipped (each would need more than study.max_steps \
                     steps; see results.md): raise study.max_steps or coarsen the grid"
                );
                return 1;
            }
            0
        }
        Err(e) => {
            eprintln!("error: {e}");
            1
        }
    }
}
