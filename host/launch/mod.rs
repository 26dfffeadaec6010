//! Where kernels run: the [`Launcher`] trait is the seam between the CPU and the GPU (as
//! candle's backend trait): [`Rayon`] runs each kernel's thread function for every thread index
//! on this machine's cores, [`Cuda`] launches its PTX entry point (the same Rust code compiled
//! by rustc's NVPTX backend, embedded in the binary) through the CUDA driver, loaded at run
//! time. The engine is generic over it, so `--device cpu` runs the very step a GPU runs,
//! launches and buffers included. Kernels are named by the kernel table
//! (`dustsph_device::kernel_table`), one constant per kernel for both launchers.
pub mod cuda;
pub mod rayon;

pub use self::cuda::{probe, register_cap, Cuda, PTX, PTX_NOTE};
pub use self::rayon::Rayon;
use dustsph_device::kernel_table::Kernel;

#[derive(Debug, Clone)]
pub struct GpuError(pub String);

impl std::fmt::Display for GpuError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for GpuError {}

impl From<::cudarc::driver::DriverError> for GpuError {
    fn from(e: ::cudarc::driver::DriverError) -> Self {
        GpuError(format!("CUDA driver: {e}"))
    }
}

/// What the engine needs from where it runs: zeroed memory, copies, launches.
pub trait Launcher {
    type Mem;
    /// Device name for the summary.
    fn describe(&self) -> String;
    /// `bytes` of zeroed memory (at least one byte is allocated).
    fn alloc(&self, bytes: usize) -> Result<Self::Mem, GpuError>;
    /// The address kernels see.
    fn addr(&self, m: &Self::Mem) -> u64;
    fn upload(&self, m: &mut Self::Mem, bytes: &[u8]) -> Result<(), GpuError>;
    fn download(&self, m: &Self::Mem, out: &mut [u8]) -> Result<(), GpuError>;
    /// Write one value at the start of `m` (a kernel's parameter block; typed, so the
    /// struct's padding is never read as bytes on the host).
    fn upload_value<T: Copy>(&self, m: &mut Self::Mem, v: &T) -> Result<(), GpuError>;
    /// Zero the first `bytes` bytes on the device (no host copy).
    fn zero(&self, m: &mut Self::Mem, bytes: usize) -> Result<(), GpuError>;
    /// Run `threads` threads of kernel `k` (its PTX entry point on a GPU, its thread function
    /// on the CPU: one constant of the kernel table names both).
    fn launch<A: Copy>(&self, k: Kernel<A>, threads: usize, args: &A) -> Result<(), GpuError>;
    /// Whether `numerics.neighbour_list = "auto"` builds neighbour lists here: measured on
    /// the CPU (docs/performance.md); the GPU kernels are built without them.
    fn lists_by_default(&self) -> bool {
        true
    }
    /// Into how many chunks of particles, each one thread's in order, the kernel coupling's
    /// deposit rows are transposed (`th::DepositRowsArgs::chunk`); 0: one thread per particle
    /// with atomic cursors and a sort of each row (the GPU's form). The rows come out the same.
    fn deposit_chunks(&self) -> usize {
        4 * ::rayon::current_num_threads()
    }
    /// A wait for the work issued so far, for stage timers (none where launches return only
    /// when done, as on the CPU).
    fn sync_hook(&self) -> Option<crate::step::timers::SyncHook> {
        None
    }
}

/// "1 thread", "n threads".
pub fn threads(n: usize) -> String {
    if n == 1 {
        "1 thread".into()
    } else {
        format!("{n} threads")
    }
}
