//! The CUDA launcher: the embedded PTX loaded into a context of device 0 (or the rank's
//! device), one stream, a launch per kernel of the kernel table.
use super::{GpuError, Launcher};
use cudarc::driver::{
    CudaContext, CudaFunction, CudaSlice, CudaStream, DevicePtr, DevicePtrMut, DeviceRepr,
    LaunchConfig, PushKernelArg,
};
use dustsph_device::kernel_table::{self, Kernel};
use std::collections::HashMap;
use std::sync::Arc;

/// The kernels, as PTX built from `device/` by build.rs (empty when that build was skipped).
pub const PTX: &str = include_str!(concat!(env!("OUT_DIR"), "/dustsph.ptx"));
/// How the PTX was (or was not) built.
pub const PTX_NOTE: &str = env!("DUSTSPH_PTX_NOTE");

/// A kernel argument struct passed by value (every kernel takes exactly one).
#[repr(transparent)]
struct ByValue<A>(A);
// SAFETY: the argument structs are `#[repr(C)]` plain data (numbers and device addresses)
// whose layout the PTX entry points share: they are compiled from the same definitions.
unsafe impl<A> DeviceRepr for ByValue<A> {}

/// Threads per block for every launch.
const BLOCK: u32 = 256;

/// The register cap of every kernel (`.maxnreg`). On an H200, 3D box of 3.4e6 particles per
/// phase, against no cap (up to 180 registers in f32, 218 in f64): 2.09e8 against 1.30e8
/// particle-steps/s in f32, 1.46e8 against 1.07e8 in f64 (docs/gpu.md).
pub const MAX_REGISTERS: u32 = 64;

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
                PTX_NOTE
            )));
        }
        probe().map_err(GpuError)?;
        let ctx = CudaContext::new(ordinal)?;
        let stream = ctx.default_stream();
        let cap = register_cap().map_err(GpuError)?;
        let capped = cap.map(|n| cap_registers(ptx, n));
        let ptx = capped.as_deref().unwrap_or(ptx);
        let module = ctx.load_module(cudarc::nvrtc::Ptx::from_src(ptx))?;
        let mut funcs = HashMap::new();
        for &k in kernel_table::NAMES {
            funcs.insert(k, module.load_function(k)?);
        }
        let (free, total) = ctx.mem_get_info()?;
        // The cap is part of how a run was made (summary.json's backend).
        let name = format!(
            "{} (CUDA device {ordinal}, {:.1} of {:.1} GiB free, {})",
            ctx.name()?,
            free as f64 / (1u64 << 30) as f64,
            total as f64 / (1u64 << 30) as f64,
            cap.map_or("registers uncapped".into(), |n| format!(
                "at most {n} registers a thread"
            ))
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

/// The register cap the kernels are loaded with (occupancy against spills; docs/gpu.md):
/// [`MAX_REGISTERS`], or `DUSTSPH_PTX_MAXNREG=N` (16–255), or `=off` for none.
pub fn register_cap() -> Result<Option<u32>, String> {
    match crate::env::var("DUSTSPH_PTX_MAXNREG") {
        None => Ok(Some(MAX_REGISTERS)),
        Some(v) if v.trim() == "off" => Ok(None),
        Some(v) => match v.trim().parse::<u32>() {
            Ok(n) if (16..=255).contains(&n) => Ok(Some(n)),
            _ => Err(format!(
                "DUSTSPH_PTX_MAXNREG={v}: a register count from 16 to 255, or off"
            )),
        },
    }
}

/// `ptx` with `.maxnreg n` on every entry point (PTX ISA: a performance-tuning directive
/// between an entry's parameters and its body).
fn cap_registers(ptx: &str, n: u32) -> String {
    let mut out = String::with_capacity(ptx.len() + 4096);
    let mut in_entry_head = false;
    for line in ptx.lines() {
        if line.starts_with(".visible .entry ") || line.starts_with(".entry ") {
            in_entry_head = true;
        } else if in_entry_head && line.trim() == "{" {
            out.push_str(&format!(".maxnreg {n}\n"));
            in_entry_head = false;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

impl Launcher for Cuda {
    fn lists_by_default(&self) -> bool {
        false
    }

    fn deposit_chunks(&self) -> usize {
        0
    }

    fn sync_hook(&self) -> Option<crate::step::timers::SyncHook> {
        let stream = self.stream.clone();
        // An error here is the stream's: the next launch or copy reports it.
        Some(Arc::new(move || {
            let _ = stream.synchronize();
        }))
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

#[cfg(test)]
mod tests {
    #[test]
    fn a_register_cap_is_written_before_each_entry_body_only() {
        let ptx = ".func f(\n)\n{\n}\n.visible .entry k(\n\t.param .u64 a\n)\n{\n\tret;\n}\n";
        let c = super::cap_registers(ptx, 96);
        assert_eq!(c.matches(".maxnreg 96").count(), 1);
        assert!(c.contains(")\n.maxnreg 96\n{\n\tret;"));
    }
}
