//! GPU entry points: one `extern "ptx-kernel"` per kernel of [`crate::threads`], each computing
//! its global thread index and calling the shared thread function. Compiled only for `nvptx64`.
#![allow(unsafe_code)]

use crate::threads::*;
use core::arch::nvptx::{_block_dim_x, _block_idx_x, _thread_idx_x};

type V3 = [f64; 3];
type V3f32 = [f32; 3];

#[inline(always)]
fn tid() -> usize {
    // SAFETY: special-register reads, valid in any kernel.
    unsafe { _block_idx_x() as usize * _block_dim_x() as usize + _thread_idx_x() as usize }
}

macro_rules! kernels {
    ($($name:ident => $body:expr, $args:ty;)*) => {
        $(
            #[no_mangle]
            pub unsafe extern "ptx-kernel" fn $name(a: $args) {
                $body(tid(), &a)
            }
        )*
    };
}

// Kernels free of floating point: one entry each.
kernels! {
    dustsph_scan_sums => scan_sums, ScanArgs;
    dustsph_scan_totals => scan_totals, ScanArgs;
    dustsph_scan_chunks => scan_chunks, ScanArgs;
    dustsph_sort_segments => sort_segments, SegmentArgs;
    dustsph_gather_u64 => gather::<u64>, GatherArgs<u64>;
    // Positions are f64 in every precision.
    dustsph_gather_x => gather::<V3>, GatherArgs<V3>;
    dustsph_gather_u8 => gather::<u8>, GatherArgs<u8>;
}

// Per precision: f64 under the plain name, f32 with the suffix `_f32` (host: `kname`).
kernels! {
    dustsph_gather_v3 => gather::<V3>, GatherArgs<V3>;
    dustsph_gather_f64 => gather::<f64>, GatherArgs<f64>;
    dustsph_copy_v3 => copy::<V3>, CopyArgs<V3>;
    dustsph_copy_f64 => copy::<f64>, CopyArgs<f64>;
    dustsph_gather_v3_f32 => gather::<V3f32>, GatherArgs<V3f32>;
    dustsph_gather_f32 => gather::<f32>, GatherArgs<f32>;
    dustsph_copy_v3_f32 => copy::<V3f32>, CopyArgs<V3f32>;
    dustsph_copy_f32 => copy::<f32>, CopyArgs<f32>;
    dustsph_bounds => bounds::<f64>, BoundsArgs<f64>;
    dustsph_keys => keys::<f64>, KeysArgs<f64>;
    dustsph_scatter => scatter::<f64>, ScatterArgs<f64>;
    dustsph_density => density::<f64>, DensityArgs<f64>;
    dustsph_density_continuity => density_continuity::<f64>, DensityArgs<f64>;
    dustsph_explicit_limit => explicit_limit::<f64>, LimitArgs<f64>;
    dustsph_eos => eos::<f64>, EosArgs<f64>;
    dustsph_forces => forces::<f64>, ForcesArgs<f64>;
    dustsph_solve_h => solve_h::<f64>, HSolveArgs<f64>;
    dustsph_force_prep => force_prep::<f64>, PrepArgs<f64>;
    dustsph_iad_matrix => iad_matrix::<f64>, IadArgs<f64>;
    dustsph_max_of => max_of::<f64>, MaxArgs<f64>;
    dustsph_union_flags => union_flags::<f64>, UnionArgs<f64>;
    dustsph_union_keys => union_keys::<f64>, UnionArgs<f64>;
    dustsph_cell_step => cell_step::<f64>, CellArgs<f64>;
    dustsph_gas_kick => gas_kick::<f64>, KickArgs<f64>;
    dustsph_dust_kick => dust_kick::<f64>, KickArgs<f64>;
    dustsph_heat => heat::<f64>, HeatArgs<f64>;
    dustsph_drift => drift::<f64>, DriftArgs<f64>;
    dustsph_energy => energy::<f64>, EnergyArgs<f64>;
    dustsph_check => check::<f64>, CheckArgs<f64>;
    dustsph_dust_accel => dust_accel::<f64>, DustAccelArgs<f64>;
    dustsph_coupling_norm => coupling_norm::<f64>, NormArgs<f64>;
    dustsph_coupling_solve => coupling_solve::<f64>, CoupleArgs<f64>;
    dustsph_coupling_return => coupling_return::<f64>, ReturnArgs<f64>;
    dustsph_coupling_tstop => coupling_tstop::<f64>, ReturnArgs<f64>;
    dustsph_coupling_heat => coupling_heat::<f64>, CouplingHeatArgs<f64>;
    dustsph_coupling_scatter => coupling_scatter::<f64>, ScatterDepositArgs<f64>;
    dustsph_coupling_solve_sums => coupling_solve_sums::<f64>, ScatterDepositArgs<f64>;
    dustsph_bounds_f32 => bounds::<f32>, BoundsArgs<f32>;
    dustsph_keys_f32 => keys::<f32>, KeysArgs<f32>;
    dustsph_scatter_f32 => scatter::<f32>, ScatterArgs<f32>;
    dustsph_density_f32 => density::<f32>, DensityArgs<f32>;
    dustsph_density_continuity_f32 => density_continuity::<f32>, DensityArgs<f32>;
    dustsph_explicit_limit_f32 => explicit_limit::<f32>, LimitArgs<f32>;
    dustsph_eos_f32 => eos::<f32>, EosArgs<f32>;
    dustsph_forces_f32 => forces::<f32>, ForcesArgs<f32>;
    dustsph_solve_h_f32 => solve_h::<f32>, HSolveArgs<f32>;
    dustsph_force_prep_f32 => force_prep::<f32>, PrepArgs<f32>;
    dustsph_iad_matrix_f32 => iad_matrix::<f32>, IadArgs<f32>;
    dustsph_max_of_f32 => max_of::<f32>, MaxArgs<f32>;
    dustsph_union_flags_f32 => union_flags::<f32>, UnionArgs<f32>;
    dustsph_union_keys_f32 => union_keys::<f32>, UnionArgs<f32>;
    dustsph_cell_step_f32 => cell_step::<f32>, CellArgs<f32>;
    dustsph_gas_kick_f32 => gas_kick::<f32>, KickArgs<f32>;
    dustsph_dust_kick_f32 => dust_kick::<f32>, KickArgs<f32>;
    dustsph_heat_f32 => heat::<f32>, HeatArgs<f32>;
    dustsph_drift_f32 => drift::<f32>, DriftArgs<f32>;
    dustsph_energy_f32 => energy::<f32>, EnergyArgs<f32>;
    dustsph_check_f32 => check::<f32>, CheckArgs<f32>;
    dustsph_dust_accel_f32 => dust_accel::<f32>, DustAccelArgs<f32>;
    dustsph_coupling_norm_f32 => coupling_norm::<f32>, NormArgs<f32>;
    dustsph_coupling_solve_f32 => coupling_solve::<f32>, CoupleArgs<f32>;
    dustsph_coupling_return_f32 => coupling_return::<f32>, ReturnArgs<f32>;
    dustsph_coupling_tstop_f32 => coupling_tstop::<f32>, ReturnArgs<f32>;
    dustsph_coupling_heat_f32 => coupling_heat::<f32>, CouplingHeatArgs<f32>;
    dustsph_coupling_scatter_f32 => coupling_scatter::<f32>, ScatterDepositArgs<f32>;
    dustsph_coupling_solve_sums_f32 => coupling_solve_sums::<f32>, ScatterDepositArgs<f32>;
}
