//! What the `dustsph` subcommands do, one module each, over the library's stages: `run` and
//! `resume` ([`run`]), `study` ([`study`]), `stiffness` ([`stiffness`]), `bench` ([`bench`]),
//! `parity` ([`parity`]), `profile` ([`profile`]). `host/main.rs` only parses arguments and
//! calls these.
pub mod bench;
pub mod parity;
pub mod profile;
pub mod run;
pub mod stiffness;
pub mod study;
