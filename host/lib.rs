//! dustsph: gas + polydisperse dust by SPH with implicit drag in cell (IDIC).
//!
//! Data flow, one module per stage (docs/architecture.md): [`scene`] (TOML → the scene model)
//! → [`setup`] (initial particles) → [`sim`] (the simulation and its step loop, with its
//! outputs) → [`step`] (the step: the engine on a [`launch`] launcher; physics formulas in
//! `dustsph-device`) → [`io`] (snapshots, checkpoints, summary) with [`analysis`] (errors
//! against [`exact`] solutions) and [`plot`]; [`dist`] runs over MPI ranks. The subcommands
//! live in [`commands`].
pub mod analysis;
pub mod commands;
pub mod decomp;
pub mod dist;
pub mod env;
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
