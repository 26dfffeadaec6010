//! Complex numbers for the linear-wave oracles: num-complex's `Complex64`.
pub use num_complex::Complex64 as C;
