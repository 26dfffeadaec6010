//! Exact and discrete-exact reference solutions for the 1D test problems (method.md §5, §7):
//! DUSTYBOX, DUSTYWAVE (any number of fractions, isothermal or adiabatic) and the Riemann /
//! equilibrium dusty shock tube. Pure std, f64 interfaces; the stiff matrix functions work in
//! double-double internally (see `linalg`).
pub mod complex;
pub mod drift;
pub mod dustybox;
pub mod dustywave;
pub mod linalg;
pub mod riemann;
pub mod settle;

pub use complex::C;
pub use dustybox::DustyBox;
pub use dustywave::{LinearWave, WaveAmplitudes, WaveGas};
pub use riemann::{DustyRiemann, Prim, RiemannSolution, Wave};
