//! Where kernels run: a real GPU through the CUDA driver ([`Cuda`]), or this machine's cores
//! ([`Rayon`]), which runs the very thread functions the PTX entry points call. The step is
//! one pipeline of launches over resident buffers; these are its two launchers, so the CPU
//! path (`--device cpu`) *is* the GPU step, launches and buffers included.
use cudarc::driver::{
    CudaContext, CudaFunction, CudaSlice, CudaStream, DevicePtr, DevicePtrMut, DeviceRepr,
    LaunchConfig, PushKernelArg,
};
use dustsph_device::kernel_table::{self, Kernel};
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;

#[derive(Debug, Clone)]
pub struct GpuError(pub String);

impl std::fmt::Display for GpuError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for GpuError {}

impl From<cudarc::driver::DriverError> for GpuError {
    fn from(e: cudarc::driver::DriverError) -> Self {
        GpuError(format!("CUDA driver: {e}"))
    }
}

/// What the GPU engine needs from a device: zeroed memory, copies, launches.
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
}

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

/// A kernel argument struct passed by value (every kernel takes exactly one).
#[repr(transparent)]
struct ByValue<A>(A);
// SAFETY: the argument structs are `#[repr(C)]` plain data (numbers and device addresses)
// whose layout the PTX entry points share: they are compiled from the same definitions.
unsafe impl<A> DeviceRepr for ByValue<A> {}

/// Threads per block for every launch.
const BLOCK: u32 = 256;

/// An NVIDIA GPU through the CUDA driver (loaded at run time), one stream. Clones share the
/// context, the stream and the loaded kernels.
#[derive(Clone)]
pub struct Cuda {
    ctx: Arc<CudaContext>,
    stream: Arc<CudaStream>,
    funcs: HashMap<&'static str, CudaFunction>,
    name: String,
}

/// Whether a CUDA device can be used, without panicking where there is no driver:
/// `Ok(name of device 0)` or `Err(why not)`.
pub fn probe() -> Result<String, String> {
    // SAFETY: only checks whether libcuda can be loaded.
    if !unsafe { cudarc::driver::sys::is_culib_present() } {
        return Err("no CUDA driver (libcuda) on this machine".into());
    }
    let n = CudaContext::device_count().map_err(|e| format!("CUDA driver: {e}"))?;
    if n < 1 {
        return Err("the CUDA driver reports no device".into());
    }
    let ctx = CudaContext::new(0).map_err(|e| format!("CUDA device 0: {e}"))?;
    ctx.name().map_err(|e| format!("CUDA device 0: {e}"))
}

/// "1 thread", "n threads".
pub fn threads(n: usize) -> String {
    if n == 1 {
        "1 thread".into()
    } else {
        format!("{n} threads")
    }
}

/// How many CUDA devices this process sees (after [`probe`]).
pub fn device_count() -> Result<usize, String> {
    probe()?;
    let n = CudaContext::device_count().map_err(|e| format!("CUDA driver: {e}"))?;
    Ok(n.max(0) as usize)
}

impl Cuda {
    /// Device `ordinal` with the embedded kernels loaded.
    pub fn new(ordinal: usize, ptx: &str) -> Result<Cuda, GpuError> {
        if ptx.is_empty() {
            return Err(GpuError(format!(
                "this binary has no GPU kernels ({}); build with the nightly toolchain and rust-src",
                super::PTX_NOTE
            )));
        }
        probe().map_err(GpuError)?;
        let ctx = CudaContext::new(ordinal)?;
        let stream = ctx.default_stream();
        let module = ctx.load_module(cudarc::nvrtc::Ptx::from_src(ptx))?;
        let mut funcs = HashMap::new();
        for &k in kernel_table::NAMES {
            funcs.insert(k, module.load_function(k)?);
        }
        let (free, total) = ctx.mem_get_info()?;
        let name = format!(
            "{} (CUDA device {ordinal}, {:.1} of {:.1} GiB free)",
            ctx.name()?,
            free as f64 / (1u64 << 30) as f64,
            total as f64 / (1u64 << 30) as f64
        );
        Ok(Cuda {
            ctx,
            stream,
            funcs,
            name,
        })
    }

    pub fn synchronize(&self) -> Result<(), GpuError> {
        Ok(self.stream.synchronize()?)
    }

    /// Free device memory, in bytes.
    pub fn memory_free(&self) -> Result<usize, GpuError> {
        Ok(self.ctx.mem_get_info()?.0)
    }

    pub fn memory_used(&self) -> Result<usize, GpuError> {
        let (free, total) = self.ctx.mem_get_info()?;
        Ok(total - free)
    }
}

impl Launcher for Cuda {
    fn lists_by_default(&self) -> bool {
        false
    }

    type Mem = CudaSlice<u8>;

    fn describe(&self) -> String {
        self.name.clone()
    }

    fn alloc(&self, bytes: usize) -> Result<CudaSlice<u8>, GpuError> {
        Ok(self.stream.alloc_zeros::<u8>(bytes.max(1))?)
    }

    fn addr(&self, m: &CudaSlice<u8>) -> u64 {
        let (p, _sync) = m.device_ptr(&self.stream);
        p
    }

    fn upload(&self, m: &mut CudaSlice<u8>, bytes: &[u8]) -> Result<(), GpuError> {
        if bytes.is_empty() {
            return Ok(());
        }
        let mut view = m.slice_mut(0..bytes.len());
        self.stream.memcpy_htod(bytes, &mut view)?;
        Ok(())
    }

    fn download(&self, m: &CudaSlice<u8>, out: &mut [u8]) -> Result<(), GpuError> {
        if out.is_empty() {
            return Ok(());
        }
        let view = m.slice(0..out.len());
        self.stream.memcpy_dtoh(&view, out)?;
        self.stream.synchronize()?;
        Ok(())
    }

    fn upload_value<T: Copy>(&self, m: &mut CudaSlice<u8>, v: &T) -> Result<(), GpuError> {
        assert!(
            std::mem::size_of::<T>() <= m.len(),
            "value larger than its buffer"
        );
        let (dst, _sync) = m.device_ptr_mut(&self.stream);
        // SAFETY: `dst` holds at least size_of::<T>() bytes (checked); the copy is ordered on
        // the engine's one stream, after the launches issued before it and before those after
        // it; from pageable host memory the driver stages `v` before returning.
        unsafe {
            cudarc::driver::result::memcpy_htod_async(
                dst,
                std::slice::from_ref(v),
                self.stream.cu_stream(),
            )
        }?;
        Ok(())
    }

    fn zero(&self, m: &mut CudaSlice<u8>, bytes: usize) -> Result<(), GpuError> {
        if bytes == 0 {
            return Ok(());
        }
        let mut view = m.slice_mut(0..bytes);
        self.stream.memset_zeros(&mut view)?;
        Ok(())
    }

    fn launch<A: Copy>(&self, k: Kernel<A>, threads: usize, args: &A) -> Result<(), GpuError> {
        let name = k.name;
        if threads == 0 {
            return Ok(());
        }
        let f = self
            .funcs
            .get(name)
            .ok_or_else(|| GpuError(format!("kernel {name} is not in the PTX")))?;
        let blocks = threads.div_ceil(BLOCK as usize);
        let cfg = LaunchConfig {
            grid_dim: (blocks as u32, 1, 1),
            block_dim: (BLOCK, 1, 1),
            shared_mem_bytes: 0,
        };
        let arg = ByValue(*args);
        let mut b = self.stream.launch_builder(f);
        b.arg(&arg);
        // SAFETY: the argument struct matches the entry point's parameter (same definition),
        // and its addresses point into live allocations of this context sized for `threads`.
        unsafe { b.launch(cfg) }?;
        Ok(())
    }
}
