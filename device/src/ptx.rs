//! GPU entry points: one `extern "ptx-kernel"` per kernel of the kernel table
//! ([`crate::kernel_table`]), each computing its global thread index and calling the thread
//! function the CPU launcher runs. Compiled only for `nvptx64`; the names come from the table.
#![allow(unsafe_code)]

use crate::kernel_table::kernel_table;
use core::arch::nvptx::{_block_dim_x, _block_idx_x, _thread_idx_x};

#[inline(always)]
fn tid() -> usize {
    // SAFETY: special-register reads, valid in any kernel.
    unsafe { _block_idx_x() as usize * _block_dim_x() as usize + _thread_idx_x() as usize }
}

macro_rules! entry_points {
    (
        fixed { $($c:ident : $f:ident ($a:ty)),* $(,)? }
        float { $($fc:ident : $ff:ident ($fa:ident)),* $(,)? }
    ) => {
        $(
            #[allow(non_snake_case)]
            mod $c {
                use crate::threads::*;
                #[export_name = concat!("dustsph_", stringify!($f))]
                pub unsafe extern "ptx-kernel" fn entry(a: $a) {
                    $f(super::tid(), &a)
                }
            }
        )*
        mod f64_entries {
            $(
                #[allow(non_snake_case)]
                mod $fc {
                    use crate::threads::*;
                    #[export_name = concat!("dustsph_", stringify!($ff))]
                    pub unsafe extern "ptx-kernel" fn entry(a: $fa<f64>) {
                        $ff::<f64>(super::super::tid(), &a)
                    }
                }
            )*
        }
        mod f32_entries {
            $(
                #[allow(non_snake_case)]
                mod $fc {
                    use crate::threads::*;
                    #[export_name = concat!("dustsph_", stringify!($ff), "_f32")]
                    pub unsafe extern "ptx-kernel" fn entry(a: $fa<f32>) {
                        $ff::<f32>(super::super::tid(), &a)
                    }
                }
            )*
        }
    };
}

kernel_table!(entry_points);
