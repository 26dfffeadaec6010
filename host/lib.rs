//! dustsph: gas + polydisperse dust by SPH with implicit drag in cell (IDIC).
//!
//! Data flow, one module per stage: [`scene`] (TOML → validated scene) → [`setup`] (initial
//! particles) → [`engine`] (the step, on a backend; physics formulas in `dustsph-device`) →
//! [`io`] (snapshots, summary) with [`analysis`] (errors against [`exact`] solutions).
pub mod analysis;
pub mod bench;
pub mod engine;
pub mod exact;
pub mod grid;
pub mod io;
pub mod parity;
pub mod particles;
pub mod plot;
pub mod post;
pub mod run;
pub mod scene;
pub mod setup;
pub mod stiffness;
pub mod study;
