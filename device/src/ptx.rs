//! GPU entry points: one `extern "ptx-kernel"` per kernel of [`crate::threads`], each computing
//! its global thread index and calling the shared thread function. Compiled only for `nvptx64`.
#![allow(unsafe_code)]

use crate::threads::*;
use core::arch::nvptx::{_block_dim_x, _block_idx_x, _thread_idx_x};

type V3 = [f64; 3];

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

kernels! {
    dustsph_bounds => bounds, BoundsArgs;
    dustsph_keys => keys, KeysArgs;
    dustsph_scan_sums => scan_sums, ScanArgs;
    dustsph_scan_totals => scan_totals, ScanArgs;
    dustsph_scan_chunks => scan_chunks, ScanArgs;
    dustsph_scatter => scatter, ScatterArgs;
    dustsph_sort_segments => sort_segments, SegmentArgs;
    dustsph_gather_v3 => gather::<V3>, GatherArgs<V3>;
    dustsph_gather_f64 => gather::<f64>, GatherArgs<f64>;
    dustsph_gather_u64 => gather::<u64>, GatherArgs<u64>;
    dustsph_gather_u8 => gather::<u8>, GatherArgs<u8>;
    dustsph_copy_v3 => copy::<V3>, CopyArgs<V3>;
    dustsph_copy_f64 => copy::<f64>, CopyArgs<f64>;
    dustsph_density => density, DensityArgs;
    dustsph_density_continuity => density_continuity, DensityArgs;
    dustsph_explicit_limit => explicit_limit, LimitArgs;
    dustsph_eos => eos, EosArgs;
    dustsph_forces => forces, ForcesArgs;
    dustsph_solve_h => solve_h, HSolveArgs;
    dustsph_force_prep => force_prep, PrepArgs;
    dustsph_iad_matrix => iad_matrix, IadArgs;
    dustsph_max_of => max_of, MaxArgs;
    dustsph_union_flags => union_flags, UnionArgs;
    dustsph_union_keys => union_keys, UnionArgs;
    dustsph_cell_step => cell_step, CellArgs;
    dustsph_gas_kick => gas_kick, KickArgs;
    dustsph_dust_kick => dust_kick, KickArgs;
    dustsph_heat => heat, HeatArgs;
    dustsph_drift => drift, DriftArgs;
    dustsph_energy => energy, EnergyArgs;
    dustsph_check => check, CheckArgs;
    dustsph_dust_accel => dust_accel, DustAccelArgs;
    dustsph_coupling_norm => coupling_norm, NormArgs;
    dustsph_coupling_solve => coupling_solve, CoupleArgs;
    dustsph_coupling_return => coupling_return, ReturnArgs;
    dustsph_coupling_tstop => coupling_tstop, ReturnArgs;
    dustsph_coupling_heat => coupling_heat, CouplingHeatArgs;
    dustsph_coupling_scatter => coupling_scatter, ScatterDepositArgs;
    dustsph_coupling_solve_sums => coupling_solve_sums, ScatterDepositArgs;
}
