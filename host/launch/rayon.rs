//! The CPU launcher: every kernel's thread function for every thread index on rayon's pool.
use super::{threads, GpuError, Launcher};
use ::rayon::prelude::*;
use dustsph_device::kernel_table::Kernel;

/// Host memory, 8-byte aligned.
pub struct HostMem(Vec<u64>);

/// The CPU launcher: runs each kernel's thread function for every thread index on rayon's
/// pool (the same f64 operations as the PTX: round-to-nearest, no contraction).
#[derive(Default)]
pub struct Rayon;

struct Shared<'a, A>(&'a A);
// SAFETY: the kernels' contract (threads.rs) — distinct threads write distinct elements or use
// atomics — is what makes running thread functions concurrently sound.
unsafe impl<A> Sync for Shared<'_, A> {}

impl Launcher for Rayon {
    type Mem = HostMem;

    fn describe(&self) -> String {
        format!("rayon, {}", threads(rayon::current_num_threads()))
    }

    fn alloc(&self, bytes: usize) -> Result<HostMem, GpuError> {
        Ok(HostMem(vec![0u64; bytes.div_ceil(8).max(1)]))
    }

    fn addr(&self, m: &HostMem) -> u64 {
        m.0.as_ptr() as u64
    }

    fn upload(&self, m: &mut HostMem, bytes: &[u8]) -> Result<(), GpuError> {
        // SAFETY: the u64 buffer holds at least `bytes.len()` bytes (checked by the caller's
        // typed wrapper), and u8 has no alignment requirement.
        let dst =
            unsafe { std::slice::from_raw_parts_mut(m.0.as_mut_ptr() as *mut u8, m.0.len() * 8) };
        dst[..bytes.len()].copy_from_slice(bytes);
        Ok(())
    }

    fn download(&self, m: &HostMem, out: &mut [u8]) -> Result<(), GpuError> {
        // SAFETY: as in `upload`.
        let src = unsafe { std::slice::from_raw_parts(m.0.as_ptr() as *const u8, m.0.len() * 8) };
        out.copy_from_slice(&src[..out.len()]);
        Ok(())
    }

    fn upload_value<T: Copy>(&self, m: &mut HostMem, v: &T) -> Result<(), GpuError> {
        assert!(
            std::mem::size_of::<T>() <= m.0.len() * 8 && std::mem::align_of::<T>() <= 8,
            "value larger than its buffer"
        );
        // SAFETY: the buffer is 8-byte aligned and large enough (checked above).
        unsafe { std::ptr::write(m.0.as_mut_ptr() as *mut T, *v) };
        Ok(())
    }

    fn zero(&self, m: &mut HostMem, bytes: usize) -> Result<(), GpuError> {
        // Whole words: the buffer is u64-backed and callers zero from the start.
        let words = bytes.div_ceil(8).min(m.0.len());
        m.0[..words].fill(0);
        Ok(())
    }

    fn launch<A: Copy>(&self, k: Kernel<A>, threads: usize, args: &A) -> Result<(), GpuError> {
        let f = k.thread;
        let a = Shared(args);
        (0..threads).into_par_iter().for_each(|t| {
            let a = &a;
            // SAFETY: the engine built `args` over live buffers sized for `threads`.
            unsafe { f(t, a.0) }
        });
        Ok(())
    }
}
