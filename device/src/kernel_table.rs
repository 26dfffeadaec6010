//! The kernel table: every kernel of the step declared once, as (constant, thread function,
//! argument struct). From this one list come
//! - the host's [`Kernel`] constants, each carrying its PTX entry point's name *and* the thread
//!   function the CPU launcher runs (both launchers take the same constant, so a launch cannot
//!   run one kernel on the CPU and another on the GPU);
//! - the PTX entry points (`ptx.rs`, compiled for `nvptx64`), named from the same identifiers;
//! - [`NAMES`] and [`ARG_BYTES`], which the CUDA launcher loads and the PTX check compares.
//!
//! A kernel's entry point is `dustsph_<thread function>`, with `_f32` appended for the f32
//! instantiation of a float kernel. Kernels free of floating point have one entry point.
use crate::threads::*;

/// One kernel: the name of its PTX entry point and the per-thread function the CPU launcher
/// calls for every thread index (the entry point calls the same function on the GPU).
pub struct Kernel<A> {
    pub name: &'static str,
    pub thread: unsafe fn(usize, &A),
}

// Copy, not derived: a derive would require `A: Copy` of every argument struct's parameter.
impl<A> Clone for Kernel<A> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<A> Copy for Kernel<A> {}

/// Calls `$m!` with the table. `fixed`: kernels without floating point (one entry point each,
/// argument type as written); `float`: kernels instantiated for f64 and f32 (argument struct
/// `Args<R>`, thread function `f::<R>`).
macro_rules! kernel_table {
    ($m:ident) => {
        $m! {
            fixed {
                SCAN_SUMS: scan_sums(ScanArgs),
                SCAN_TOTALS: scan_totals(ScanArgs),
                SCAN_CHUNKS: scan_chunks(ScanArgs),
                SORT_SEGMENTS: sort_segments(SegmentArgs),
                GATHER_U64: gather_u64(GatherArgs<u64>),
                GATHER_U8: gather_u8(GatherArgs<u8>),
                // Positions are f64 in every precision.
                GATHER_X: gather_x(GatherArgs<[f64; 3]>),
                BOUNDS: bounds(BoundsArgs),
                PACK_ROWS: pack_rows(RowsArgs),
                UNPACK_ROWS: unpack_rows(RowsArgs),
            }
            float {
                KEYS: keys(KeysArgs),
                SCATTER: scatter(ScatterArgs),
                GATHER_V3: gather_v3(GatherV3Args),
                GATHER_REAL: gather_real(GatherArgs),
                COPY_V3: copy_v3(CopyV3Args),
                COPY_REAL: copy_real(CopyArgs),
                DENSITY: density(DensityArgs),
                DENSITY_CONTINUITY: density_continuity(DensityArgs),
                EOS: eos(EosArgs),
                FORCES: forces(ForcesArgs),
                SOLVE_H: solve_h(HSolveArgs),
                FORCE_PREP: force_prep(PrepArgs),
                IAD_MATRIX: iad_matrix(IadArgs),
                MAX_OF: max_of(MaxArgs),
                UNION_FLAGS: union_flags(UnionArgs),
                UNION_KEYS: union_keys(UnionArgs),
                CELL_STEP: cell_step(CellArgs),
                EXPLICIT_LIMIT: explicit_limit(LimitArgs),
                GAS_KICK: gas_kick(KickArgs),
                DUST_KICK: dust_kick(KickArgs),
                HEAT: heat(HeatArgs),
                DRIFT: drift(DriftArgs),
                ENERGY: energy(EnergyArgs),
                CHECK: check(CheckArgs),
                DUST_ACCEL: dust_accel(DustAccelArgs),
                DUST_ACCEL_LIMIT: dust_accel_limit(DustLimitArgs),
                COUPLING_ROWS: coupling_rows(PairRowsArgs),
                COUPLING_DEPOSIT_COUNT: coupling_deposit_count(DepositRowsArgs),
                COUPLING_DEPOSIT_TOTAL: coupling_deposit_total(DepositRowsArgs),
                COUPLING_DEPOSIT_STARTS: coupling_deposit_starts(DepositRowsArgs),
                COUPLING_DEPOSIT_FILL: coupling_deposit_fill(DepositRowsArgs),
                COUPLING_DEPOSIT_SORT: coupling_deposit_sort(DepositRowsArgs),
                COUPLING_SOLVE: coupling_solve(CoupleArgs),
                COUPLING_SCATTER: coupling_scatter(ScatterDepositArgs),
                COUPLING_SOLVE_SUMS: coupling_solve_sums(ScatterDepositArgs),
                COUPLING_RETURN: coupling_return(ReturnArgs),
                COUPLING_TSTOP: coupling_tstop(ReturnArgs),
                COUPLING_DAMP: coupling_damp(ReturnArgs),
                COUPLING_REACT: coupling_react(CoupleArgs),
                COUPLING_HEAT: coupling_heat(CouplingHeatArgs),
                MOMENTUM: momentum(MomentumArgs),
            }
        }
    };
}
#[allow(unused_imports)] // used by ptx.rs (nvptx64 only)
pub(crate) use kernel_table;

macro_rules! host_table {
    (
        fixed { $($c:ident : $f:ident ($a:ty)),* $(,)? }
        float { $($fc:ident : $ff:ident ($fa:ident)),* $(,)? }
    ) => {
        $(
            pub const $c: Kernel<$a> = Kernel {
                name: concat!("dustsph_", stringify!($f)),
                thread: $f,
            };
        )*

        /// The float kernels of one precision (`R::FORCES`, …): implemented for f64 and f32.
        pub trait FloatKernels: Sized + 'static {
            $( const $fc: Kernel<$fa<Self>>; )*
        }

        impl FloatKernels for f64 {
            $(
                const $fc: Kernel<$fa<f64>> = Kernel {
                    name: concat!("dustsph_", stringify!($ff)),
                    thread: $ff::<f64>,
                };
            )*
        }

        impl FloatKernels for f32 {
            $(
                const $fc: Kernel<$fa<f32>> = Kernel {
                    name: concat!("dustsph_", stringify!($ff), "_f32"),
                    thread: $ff::<f32>,
                };
            )*
        }

        /// Every entry point of the PTX.
        pub const NAMES: &[&str] = &[
            $( concat!("dustsph_", stringify!($f)), )*
            $( concat!("dustsph_", stringify!($ff)), )*
            $( concat!("dustsph_", stringify!($ff), "_f32"), )*
        ];

        /// Every entry point with the bytes of its argument struct (the PTX's parameter).
        pub const ARG_BYTES: &[(&str, usize)] = &[
            $( (concat!("dustsph_", stringify!($f)), core::mem::size_of::<$a>()), )*
            $( (concat!("dustsph_", stringify!($ff)), core::mem::size_of::<$fa<f64>>()), )*
            $( (concat!("dustsph_", stringify!($ff), "_f32"), core::mem::size_of::<$fa<f32>>()), )*
        ];
    };
}

kernel_table!(host_table);

#[cfg(test)]
mod tests {
    use super::*;

    /// Each entry point's name is unique, so the loader's map holds every kernel.
    #[test]
    fn entry_point_names_are_unique() {
        for (i, a) in NAMES.iter().enumerate() {
            assert!(!NAMES[i + 1..].contains(a), "{a} twice");
        }
        assert_eq!(NAMES.len(), ARG_BYTES.len());
    }
}
