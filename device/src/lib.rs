//! dustsph physics, written once.
//!
//! Every formula of the method (kernel, equation of state, SPH pair terms, artificial
//! viscosity, stopping-time laws, the IDIC cell solve and the particle updates) lives here as
//! a plain, allocation-free function over scalars and slices. The CPU backend calls these from
//! rayon loops; GPU kernels (compiled for `nvptx64`) call the very same functions. Nothing here
//! panics on a hot path, allocates, or touches `std`.
//!
//! Functions are generic over [`Real`] so the GPU precision (f32 or f64) can be chosen by
//! measurement (`numerics.precision`, docs/accuracy.md).
#![no_std]
// Raw-pointer code is confined to `threads` (kernel entry bodies) and `ptx` (GPU entry points).
#![deny(unsafe_code)]
#![cfg_attr(
    target_arch = "nvptx64",
    feature(abi_ptx, stdarch_nvptx, core_intrinsics)
)]
// sqrt.rn.f64 comes from the sqrt intrinsic on the GPU.
#![cfg_attr(target_arch = "nvptx64", allow(internal_features))]

pub mod cell;
pub mod drag;
pub mod eos;
pub mod gravity;
pub mod grid;
pub mod kernel;
pub mod kernel_table;
pub mod kernels;
pub mod real;
pub mod sph;
pub mod threads;
pub mod timestep;
pub mod update;

#[cfg(target_arch = "nvptx64")]
pub mod ptx;

pub use real::Real;

/// A vector in up to three dimensions; unused components are zero.
pub type Vec3<R> = [R; 3];

#[inline(always)]
pub fn dot<R: Real>(a: Vec3<R>, b: Vec3<R>) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
pub fn sub<R: Real>(a: Vec3<R>, b: Vec3<R>) -> Vec3<R> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
pub fn add<R: Real>(a: Vec3<R>, b: Vec3<R>) -> Vec3<R> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a + s * b`
#[inline(always)]
pub fn axpy<R: Real>(a: Vec3<R>, s: R, b: Vec3<R>) -> Vec3<R> {
    [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]]
}

/// `a × b`
#[inline(always)]
pub fn cross<R: Real>(a: Vec3<R>, b: Vec3<R>) -> Vec3<R> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline(always)]
pub fn scale<R: Real>(s: R, a: Vec3<R>) -> Vec3<R> {
    [s * a[0], s * a[1], s * a[2]]
}
