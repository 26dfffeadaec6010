//! The grid rebuild: bounds of the particles, the grid over them, the counting sort of every
//! phase by cell (or the sparse tables of a spread-out cloud), and the neighbour lists.
use super::*;

impl<L: Launcher, R: Float> PhaseBuffers<L, R> {
    /// Sort by combined cell key (counting sort, then each cell's particles back in index
    /// order) and permute every per-particle array; `extra` are further f64 fields to carry.
    pub(super) fn sort(
        &mut self,
        d: &Device<L>,
        p: &LaunchParams<R>,
        sums: &mut Buf<L, u32>,
        extra: &mut [&mut Buf<L, R>],
        extra_v3: &mut [&mut Buf<L, [R; 3]>],
        sparse: bool,
    ) -> Result<(), GpuError> {
        self.stale_list();
        if sparse {
            self.sort_on_host(d, p)?;
        } else {
            self.ncells = 0;
            self.host_ckeys.clear();
            // The dense table has one slot per search cell of each group.
            let nkeys = self.groups * p.stride();
            d.zeroed(&mut self.dense, nkeys + 1)?;
            let ka = th::KeysArgs {
                ph: self.bufs(d),
                p: p.dev,
                counts: d.ptr(&self.dense),
            };
            d.run(R::KEYS, self.n, &ka)?;
            d.scan(&self.dense, nkeys + 1, sums)?;
            d.zeroed(&mut self.cursor, nkeys)?;
            let sa = th::ScatterArgs {
                keys: d.ptr(&self.keys),
                n: self.n as u32,
                dense: d.ptr(&self.dense),
                cursor: d.ptr(&self.cursor),
                perm: d.ptr(&self.perm),
                p: p.dev,
            };
            d.run(R::SCATTER, self.n, &sa)?;
            let seg = th::SegmentArgs {
                dense: d.ptr(&self.dense),
                nkeys: nkeys as u32,
                perm: d.ptr(&self.perm),
                keys: d.ptr(&self.keys),
                n: self.n as u32,
            };
            d.run(kt::SORT_SEGMENTS, nkeys, &seg)?;
        }
        let perm = d.ptr(&self.perm);
        let n = self.n;
        macro_rules! carry {
            ($field:expr, $scratch:expr, $kernel:expr) => {{
                let a = th::GatherArgs {
                    src: d.ptr(&$field),
                    dst: d.ptr(&$scratch),
                    perm,
                    n: n as u32,
                };
                d.run($kernel, n, &a)?;
                std::mem::swap(&mut $field, &mut $scratch);
            }};
        }
        carry!(self.x, self.s_x, kt::GATHER_X);
        carry!(self.v, self.s_v3, R::GATHER_V3);
        carry!(self.m, self.s_f64, R::GATHER_REAL);
        carry!(self.rho, self.s_f64, R::GATHER_REAL);
        carry!(self.id, self.s_u64, kt::GATHER_U64);
        carry!(self.keys, self.s_u64, kt::GATHER_U64);
        if let (Some(f), Some(s)) = (&mut self.fixed, &mut self.s_u8) {
            carry!(*f, *s, kt::GATHER_U8);
        }
        for e in extra.iter_mut() {
            carry!(**e, self.s_f64, R::GATHER_REAL);
        }
        for e in extra_v3.iter_mut() {
            carry!(**e, self.s_v3, R::GATHER_V3);
        }
        Ok(())
    }

    /// Sparse mode: keys on the device, the (key, index) sort on the host (the dense path's
    /// order), and the occupied cells' keys and starts uploaded for binary-search lookups.
    pub(super) fn sort_on_host(
        &mut self,
        d: &Device<L>,
        p: &LaunchParams<R>,
    ) -> Result<(), GpuError> {
        let ka = th::KeysArgs {
            ph: self.bufs(d),
            p: p.dev,
            counts: std::ptr::null_mut(),
        };
        d.run(R::KEYS, self.n, &ka)?;
        let keys = d.get(&self.keys, self.n)?;
        let mut kp: Vec<(u64, u32)> = keys
            .iter()
            .enumerate()
            .map(|(i, &k)| (k, i as u32))
            .collect();
        kp.par_sort_unstable();
        let perm: Vec<u32> = kp.iter().map(|&(_, i)| i).collect();
        let (mut ck, mut cs) = (Vec::new(), Vec::new());
        for (i, &(k, _)) in kp.iter().enumerate() {
            if ck.last() != Some(&k) {
                ck.push(k);
                cs.push(i as u32);
            }
        }
        cs.push(self.n as u32);
        self.ncells = ck.len();
        d.put_growing(&mut self.ckeys, &ck)?;
        d.put_growing(&mut self.cstart, &cs)?;
        self.host_ckeys = ck;
        d.put(&mut self.perm, &perm)
    }
}

impl<L: Launcher, R: Float> Engine<L, R> {
    /// Rebuild the grid over the current positions and sort every phase by cell.
    pub(super) fn regrid(&mut self) -> Result<(), StepError> {
        // New positions and order: the kernel coupling's normalisers are recomputed.
        self.norms_fresh = false;
        self.norms_kept = [None, None];
        let d = &self.d;
        let mut b = EMPTY_BOUNDS;
        for ph in [&self.gas, &self.dust] {
            if ph.n == 0 {
                continue;
            }
            d.put(&mut self.bounds, &[u64::MAX, u64::MAX, u64::MAX, 0, 0, 0])?;
            let chunk = 64usize;
            let a = th::BoundsArgs {
                x: d.ptr(&ph.x),
                n: ph.n as u32,
                chunk: chunk as u32,
                out: d.ptr(&self.bounds),
            };
            d.run(kt::BOUNDS, ph.n.div_ceil(chunk), &a)?;
            let o = d.get(&self.bounds, 6)?;
            let dec = |k: usize| from_ordered_bits(o[k]);
            b = merge_bounds(b, ([dec(0), dec(1), dec(2)], [dec(3), dec(4), dec(5)]));
        }
        let support = self.search_support()?;
        self.grid = match Grid::from_bounds(&self.phys.domain, self.phys.cell_size, support, b) {
            Ok(g) => g,
            // A run-time stop names the step, the time and the particle that caused it.
            Err(e) => {
                return Err(StepError::Grid(crate::grid::GridError(format!(
                    "step {}, t = {:e}: {e}; farthest particle: {}",
                    self.step,
                    self.t,
                    self.farthest_particle()?
                ))))
            }
        };
        // Dense start tables over the search cells of the grid box when they are small enough;
        // else (a few particles flung far away) sorted cell lists and binary searches.
        let search_cells = self.host_params(0.0).stride() as u64 - 1;
        let sparse = self.force_sparse
            || !crate::grid::dense_table_fits(search_cells, self.gas.n + self.dust.n);
        let groups = (self.gas.groups.max(self.dust.groups)) as u128;
        if groups * (self.grid.total_cells() as u128 + 1) >= 1u128 << 64 {
            return Err(StepError::Grid(crate::grid::GridError(format!(
                "step {}: the particles span {} cells: too many for 64-bit keys of {groups} \
                 groups (the cloud has spread too far for this cell size)",
                self.step,
                self.grid.total_cells()
            ))));
        }
        let p = self.params(0.0)?;
        let mut extra: Vec<&mut Buf<L, R>> = vec![&mut self.pres, &mut self.cs];
        if let Some(e) = &mut self.e {
            extra.push(e);
        }
        if let Some(h) = &mut self.sm.gas_h {
            extra.push(h);
        }
        if let Some(o) = &mut self.sm.gas_omega {
            extra.push(o);
        }
        // The leapfrog's forces follow their particles (the predictor and a resumed first step
        // read them after the sort).
        let mut extra_v3: Vec<&mut Buf<L, [R; 3]>> = Vec::new();
        if self.stages.kdk {
            extra_v3.push(&mut self.acc);
            if let Some(dedt) = &mut self.dedt {
                extra.push(dedt);
            }
            if let Some(v) = &mut self.kdk.vsig {
                extra.push(v);
            }
        }
        self.gas.sort(
            &self.d,
            &p,
            &mut self.sums,
            &mut extra,
            &mut extra_v3,
            sparse,
        )?;
        self.dust
            .sort(&self.d, &p, &mut self.sums, &mut [], &mut [], sparse)?;
        self.cells.sparse = None;
        self.cells.union_fresh = false;
        if sparse {
            // The IDIC union: every occupied cell of any phase, sorted.
            let ks = self.grid.total_cells() + 1;
            let mut u: Vec<u64> = self.gas.host_ckeys.clone();
            u.extend(self.dust.host_ckeys.iter().map(|&c| c % ks));
            u.par_sort_unstable();
            u.dedup();
            self.d.put(&mut self.cells.ukey, &u)?;
            self.cells.sparse = Some(u.len() as u32);
        }
        self.reset_list()?;
        self.ghost_masks()
    }

    /// A fresh neighbour list for the gas's current layer (when lists are on): emptied, to be
    /// recorded by the layer's first neighbour pass and replayed by the others (h solve or
    /// density, IAD matrices, forces). The stride grows to 9/8 of the largest count seen.
    pub(super) fn reset_list(&mut self) -> Result<(), GpuError> {
        if !self.lists || self.gas.n == 0 {
            return Ok(());
        }
        let n = self.gas.n;
        let d = &self.d;
        let mut stride = LIST_STRIDE0;
        if let Some(l) = &self.gas.nl {
            stride = l.stride;
            let most = d.get(&l.max, 1)?[0] as usize;
            if most > stride {
                stride = (most + most / 8).next_multiple_of(8);
                self.gas.nl = None;
                if stride > LIST_STRIDE_MAX {
                    // Too many neighbours for a list to pay (or to fit): the cell walk stays.
                    self.lists = false;
                    return Ok(());
                }
            }
        }
        if self.gas.nl.is_none() {
            // A list is a speed-up, never a reason to run out of memory: only while it fits
            // in a quarter of what the machine has free (host memory: the CPU launcher).
            let bytes = (n * (stride + 1) * 4) as f64;
            if crate::setup::available_memory().is_some_and(|free| bytes > 0.25 * free) {
                self.lists = false;
                return Ok(());
            }
            self.gas.nl = Some(NeighbourList {
                index: d.buf(n * stride)?,
                count: d.buf(n)?,
                max: d.buf(1)?,
                stride,
                valid: std::cell::Cell::new(false),
            });
        }
        let l = self.gas.nl.as_mut().expect("allocated above");
        d.zeroed(&mut l.count, n)?;
        l.valid.set(true);
        Ok(())
    }

    /// The grid's search radius: the support 2h; with variable h, 2 max h_a plus 0.1% (the
    /// rule of `Grid::build`, so a restart builds the same grid).
    pub(super) fn search_support(&mut self) -> Result<f64, GpuError> {
        let base = self.phys.support();
        let (Some(h), true) = (&self.sm.gas_h, self.stages.variable_h) else {
            return Ok(base);
        };
        let d = &self.d;
        d.put(&mut self.sm.hmax, &[0])?;
        let chunk = 256usize;
        let a = th::MaxArgs {
            x: d.ptr(h),
            n: self.gas.n as u32,
            chunk: chunk as u32,
            out: d.ptr(&self.sm.hmax),
        };
        d.run(R::MAX_OF, self.gas.n.div_ceil(chunk), &a)?;
        let b = d.get(&self.sm.hmax, 1)?[0];
        let hmax = if b == 0 { 0.0 } else { from_ordered_bits(b) };
        Ok(base.max(SUPPORT * hmax * (1.0 + 1e-3)))
    }
}
