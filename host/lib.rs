//! dustsph: gas + polydisperse dust by SPH with implicit drag in cell (IDIC).
//!
//! Data flow, one module per stage: [`scene`] (TOML → validated scene) → [`setup`] (initial
//! particles) → [`engine`] (the step, on a backend; physics formulas in `dustsph-device`) →
//! [`io`] (snapshots, summary) with [`analysis`] (errors against [`exact`] solutions) and
//! [`plot`]. The subcommands that drive these stages live in [`commands`].
pub mod analysis;
pub mod commands;
pub mod decomp;
pub mod dist;
pub mod exact;
pub mod grid;
pub mod io;
pub mod launch;
pub mod particles;
pub mod plot;
pub mod scene;
pub mod setup;
pub mod sim;
pub mod step;

// The commands' modules under their former paths (tests and scripts use them).
pub use commands::profile as post;
pub use commands::{bench, parity, run, stiffness, study};
