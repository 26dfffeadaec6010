//! What the `dustsph` subcommands do, one module each, over the library's stages: `run` and
//! `resume` ([`run`]), `study` ([`study`]), `stiffness` ([`stiffness`]), `bench` ([`bench`]),
//! `parity` ([`parity`]), `profile` ([`profile`]), `scaling` ([`scaling`]). `host/main.rs` only parses arguments and
//! calls these.
pub mod bench;
pub mod gpu;
pub mod mpi_check;
pub mod parity;
pub mod profile;
pub mod run;
pub mod scaling;
pub mod stiffness;
pub mod study;
