//! The drag: the IDIC cell step (method.md §3), the kernel coupling (§K), the explicit
//! baseline's limit, the velocity kick with the drag, and the stopping times for output.
use super::*;
use crate::scene::DepositRows;

impl<L: Launcher, R: Float> Engine<L, R> {
    /// The explicit drag's step limit at the current layer, [`drag::EXPLICIT_SAFETY`]/Λ with Λ
    /// the fastest drag rate of any cell; +∞ with IDIC (the drag never limits its step).
    pub fn drag_dt_limit(&mut self) -> Result<f64, StepError> {
        if !self.stages.explicit_drag {
            return Ok(f64::INFINITY);
        }
        // ε_k and t_k* do not depend on the velocities handed to the cell sums.
        self.cell_step(0.0, true)?;
        let d = &self.d;
        d.put(&mut self.limits, &[0, 0, 0])?;
        let a = th::LimitArgs {
            cells: self.cells.bufs(d),
            rate: d.ptr(&self.limits),
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            gas_ghost: self.ghost_only(0),
            dust_ghost: self.ghost_only(1),
            p: self.params(0.0)?.dev,
        };
        d.run(R::EXPLICIT_LIMIT, self.cells.ukey.len, &a)?;
        let b = d.get(&self.limits, 1)?[0];
        let rate = if b == 0 { 0.0 } else { from_ordered_bits(b) };
        Ok(if rate > 0.0 {
            dustsph_device::drag::EXPLICIT_SAFETY / rate
        } else {
            f64::INFINITY
        })
    }

    /// Union of occupied cells and the IDIC cell step at step size τ (velocities ṽ = v + τA).
    pub(super) fn cell_step(&mut self, tau: f64, acc_zero: bool) -> Result<(), GpuError> {
        let d = &self.d;
        let p = self.params(tau)?;
        let nb = p.stride();
        if self.cells.sparse.is_some() || self.cells.union_fresh {
            return self.cell_step_on_union(tau, acc_zero);
        }
        d.zeroed(&mut self.cells.uidx, nb)?;
        let mut ua = th::UnionArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            flags: d.ptr(&self.cells.uidx),
            ukey: std::ptr::null_mut(),
            p: p.dev,
        };
        d.run(R::UNION_FLAGS, nb, &ua)?;
        d.scan(&self.cells.uidx, nb, &mut self.sums)?;
        ua.ukey = d.ptr(&self.cells.ukey);
        d.run(R::UNION_KEYS, nb - 1, &ua)?;
        self.cells.union_fresh = true;
        self.cell_step_on_union(tau, acc_zero)
    }

    /// The IDIC cell step over the union built for this layer.
    pub(super) fn cell_step_on_union(&mut self, tau: f64, acc_zero: bool) -> Result<(), GpuError> {
        let d = &self.d;
        let p = self.params(tau)?;
        let ca = th::CellArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            pres: d.ptr(&self.pres),
            acc: d.ptr(if acc_zero { &self.zero_acc } else { &self.acc }),
            cells: self.cells.bufs(d),
            gas_ghost: self.ghost_only(0),
            dust_ghost: self.ghost_only(1),
            p: p.dev,
        };
        // The union count stays on the device: launch one thread per possible cell.
        d.run(R::CELL_STEP, self.cells.ukey.len, &ca)
    }

    /// The kernel coupling's buffers, with the gas ghosts (over MPI ranks) marked as left to
    /// their owners: their solve and heat are not computed here, the refresh after the pass
    /// brings them (a ghost's own, cut off at the halo's edge, would be overwritten).
    pub(super) fn coupling_bufs(&self) -> th::CouplingBufs<R> {
        let c = self.coupling.as_ref().expect("kernel coupling");
        let mut b = c.bufs(&self.d, &self.sm.kernel_at);
        if let Some(m) = (self.ghosts.as_ref()).and_then(|g| g.mask[0].as_ref()) {
            b.gas_skip = self.d.ptr(m);
        }
        b
    }

    /// The kernel coupling's pairs (its return rows) and normalisers at the current positions,
    /// unless this layer has them: one walk per particle (docs/method.md §K, "The pairs, once
    /// per layer"), a second only where a row outgrew its slots.
    pub(super) fn coupling_norms(&mut self) -> Result<(), GpuError> {
        let d = &self.d;
        let c = self.coupling.as_ref().expect("kernel coupling");
        if c.per_particle_kernels {
            // Variable h: the weights' kernels at the gas particles' current h.
            let a = th::PrepArgs {
                gas: self.gas.bufs(d),
                h: d.opt(&self.sm.gas_h),
                omega: std::ptr::null_mut(),
                pres: d.ptr(&self.pres),
                kernel_at: d.ptr(&self.sm.kernel_at),
                pt: d.ptr(&self.sm.pt),
                p: self.params(0.0)?.dev,
            };
            d.run(R::FORCE_PREP, self.gas.n, &a)?;
        }
        if self.norms_fresh {
            return Ok(());
        }
        let (ng, nd) = (self.gas.n, self.dust.n);
        loop {
            let d = &self.d;
            let c = self.coupling.as_mut().expect("kernel coupling");
            d.put(&mut c.pairs.ret_max, &[0])?;
            let c = self.coupling.as_ref().expect("kernel coupling");
            for (gas, s) in [(true, &c.s_gas), (false, &c.s_dust)] {
                let ph = if gas { &self.gas } else { &self.dust };
                let a = th::PairRowsArgs {
                    gas: self.gas.bufs(d),
                    ph: ph.bufs(d),
                    row0: if gas { 0 } else { ng as u32 },
                    s: d.ptr(s),
                    // A ghost's normaliser comes from its owner (the refresh after them): its
                    // own sum, cut off at the halo's edge, is not kept.
                    ghost: self
                        .ghosts
                        .as_ref()
                        .and_then(|g| g.mask[!gas as usize].as_ref())
                        .map_or(std::ptr::null(), |m| d.ptr(m).cast_const()),
                    kernel_at: c.bufs(d, &self.sm.kernel_at).kernel_at,
                    keep: self.norms_kept[!gas as usize]
                        .as_ref()
                        .map_or(std::ptr::null(), |k| d.ptr(k)),
                    pairs: c.pairs.bufs(d),
                    p: self.params(0.0)?.dev,
                };
                d.run(R::COUPLING_ROWS, ph.n, &a)?;
            }
            let longest = d.get(&c.pairs.ret_max, 1)?[0] as usize;
            if longest <= c.pairs.cap {
                break;
            }
            // Rows outgrew their slots (or the first layer counted them): widen and find
            // the pairs again.
            let cap = (longest + longest / 8).next_multiple_of(8);
            let c = self.coupling.as_mut().expect("kernel coupling");
            c.pairs.ret_idx = d.buf((ng + nd) * cap)?;
            c.pairs.ret_w = d.buf((ng + nd) * cap)?;
            c.pairs.cap = cap;
        }
        self.coupling
            .as_mut()
            .expect("kernel coupling")
            .pairs
            .deposits_fresh = false;
        self.norms_fresh = true;
        self.norms_kept = [None, None];
        Ok(())
    }

    /// The kernel coupling's deposit rows of this layer, unless it has them: its return rows
    /// transposed (after the normalisers' refresh: a deposit's weight is W/S of the particle
    /// that deposits), each row in ascending particle order.
    pub(super) fn coupling_deposits(&mut self) -> Result<(), GpuError> {
        let c = self.coupling.as_ref().expect("kernel coupling");
        if c.pairs.deposits_fresh {
            return Ok(());
        }
        let (ng, nd) = (self.gas.n, self.dust.n);
        let rows = ng * (1 + self.dust.groups);
        let d = &self.d;
        let p = self.params(0.0)?;
        // Chunks of at least 256 particles: fewer counters than particles.
        let chunks = match self.phys.deposit_rows {
            DepositRows::Auto => d.launcher.deposit_chunks(),
            DepositRows::Chunks => 4 * ::rayon::current_num_threads(),
            DepositRows::Atomic => 0,
        }
        .min((ng + nd).div_ceil(256));
        let chunk = if chunks > 0 {
            (ng + nd).div_ceil(chunks)
        } else {
            0
        };
        let threads = if chunk > 0 {
            (ng + nd).div_ceil(chunk)
        } else {
            ng + nd
        };
        let c = self.coupling.as_mut().expect("kernel coupling");
        d.zeroed(&mut c.pairs.dep_off, rows + 1)?;
        if chunk > 0 {
            d.zeroed(&mut c.pairs.dep_counts, threads * rows)?;
        } else {
            d.zeroed(&mut c.pairs.dep_cur, rows)?;
        }
        let c = self.coupling.as_ref().expect("kernel coupling");
        let mut a = th::DepositRowsArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            cb: c.bufs(d, &self.sm.kernel_at),
            chunk: chunk as u32,
            counts: d.ptr(&c.pairs.dep_counts),
            p: p.dev,
        };
        d.run(R::COUPLING_DEPOSIT_COUNT, threads, &a)?;
        if chunk > 0 {
            d.run(R::COUPLING_DEPOSIT_TOTAL, rows, &a)?;
        }
        d.scan(&c.pairs.dep_off, rows + 1, &mut self.sums)?;
        // The scan leaves the total after its chunk sums.
        let blocks = (rows + 1).div_ceil(SCAN_CHUNK);
        let total = d.get(&self.sums, blocks + 1)?[blocks] as usize;
        let c = self.coupling.as_mut().expect("kernel coupling");
        c.pairs.pairs = total;
        if c.pairs.dep_idx.len < total {
            let n = total + total / 8;
            c.pairs.dep_idx = d.buf(n)?;
            c.pairs.dep_w = d.buf(n)?;
        }
        a.cb = self
            .coupling
            .as_ref()
            .expect("kernel coupling")
            .bufs(d, &self.sm.kernel_at);
        if chunk > 0 {
            d.run(R::COUPLING_DEPOSIT_STARTS, rows, &a)?;
        }
        d.run(R::COUPLING_DEPOSIT_FILL, threads, &a)?;
        if chunk == 0 {
            d.run(R::COUPLING_DEPOSIT_SORT, rows, &a)?;
        }
        self.coupling
            .as_mut()
            .expect("kernel coupling")
            .pairs
            .deposits_fresh = true;
        Ok(())
    }

    /// The kernel coupling's normalisers of this layer (gas, dust; in the engine's order), where
    /// it has them: over MPI ranks, carried into the engine a rebuilt halo makes
    /// ([`Engine::keep_norms`]), whose layer is the same.
    pub fn layer_norms(&self) -> Result<Option<[Vec<f64>; 2]>, GpuError> {
        let Some(c) = self.coupling.as_ref().filter(|_| self.norms_fresh) else {
            return Ok(None);
        };
        let d = &self.d;
        Ok(Some([
            d.get_f64(&c.s_gas, self.gas.n)?,
            d.get_f64(&c.s_dust, self.dust.n)?,
        ]))
    }

    /// Take the normalisers of this layer where they are known (`given`: gas, dust, in the
    /// engine's order; NaN where not): the next normalisers' pass computes only the others.
    pub fn keep_norms(&mut self, given: [Vec<f64>; 2]) -> Result<(), GpuError> {
        if self.coupling.is_none() || self.norms_fresh {
            return Ok(());
        }
        let d = &self.d;
        let c = self.coupling.as_mut().expect("kernel coupling");
        let mut kept: [Option<Buf<L, u8>>; 2] = [None, None];
        for (k, (vals, s)) in given.iter().zip([&mut c.s_gas, &mut c.s_dust]).enumerate() {
            let n = if k == 0 { self.gas.n } else { self.dust.n };
            if vals.len() != n || n == 0 {
                continue;
            }
            let flags: Vec<u8> = vals.iter().map(|v| v.is_finite() as u8).collect();
            let r: Vec<R> = vals
                .iter()
                .map(|&v| R::from_f64(if v.is_finite() { v } else { 0.0 }))
                .collect();
            d.put(s, &r)?;
            let mut b: Buf<L, u8> = d.buf(n)?;
            d.put(&mut b, &flags)?;
            kept[k] = Some(b);
        }
        self.norms_kept = kept;
        Ok(())
    }

    /// The kernel coupling's normalisers of this layer now (those not kept computed), and the
    /// ghosts' refreshed: an engine given some ([`Engine::keep_norms`]) holds them whole at once,
    /// ghosts and owners alike (collective over ranks).
    pub fn norms_now(&mut self) -> Result<(), StepError> {
        if self.coupling.is_none() {
            return Ok(());
        }
        self.coupling_norms()?;
        self.ghost_sync(&Refresh::COUPLING_NORMS)
    }

    /// The drag pass with the kernel coupling: normalisers, the solve on every gas particle,
    /// the increments back to the gas (from ṽ) and the dust (from ũ).
    pub(super) fn kernel_coupling(&mut self, tau: f64, heat: bool) -> Result<(), StepError> {
        self.coupling_norms()?;
        // The deposits weigh each neighbour by its own norm.
        self.ghost_sync(&Refresh::COUPLING_NORMS)?;
        self.coupling_deposits()?;
        let ng = self.gas.n;
        let nf = self.dust.groups;
        let d = &self.d;
        if let Some(sums) = &mut self.coupling.as_mut().expect("kernel coupling").sums {
            d.zeroed(sums, ng * (1 + nf) * th::DEPOSIT_SLOTS)?;
        }
        let c = self.coupling.as_ref().expect("kernel coupling");
        let p = self.params(tau)?;
        let ca = th::CoupleArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            acc: d.ptr(&self.acc),
            pres: d.ptr(&self.pres),
            cb: self.coupling_bufs(),
            p: p.dev,
        };
        match &c.sums {
            Some(sums) => {
                for (ph, gas) in [(&self.gas, true), (&self.dust, false)] {
                    let sa = th::ScatterDepositArgs {
                        couple: ca,
                        ph: ph.bufs(d),
                        is_gas: gas as u32,
                        sums: d.ptr(sums),
                    };
                    d.run(R::COUPLING_SCATTER, ph.n, &sa)?;
                }
                let sa = th::ScatterDepositArgs {
                    couple: ca,
                    ph: self.gas.bufs(d),
                    is_gas: 1,
                    sums: d.ptr(sums),
                };
                d.run(R::COUPLING_SOLVE_SUMS, ng, &sa)?;
            }
            None => d.run(R::COUPLING_SOLVE, ng, &ca)?,
        }
        // The return reads the neighbouring gas particles' solves.
        self.ghost_sync(&Refresh::COUPLING_SOLVE)?;
        let d = &self.d;
        let c = self.coupling.as_ref().expect("kernel coupling");
        for (ph, gas) in [(&self.gas, true), (&self.dust, false)] {
            let ra = th::ReturnArgs {
                gas: self.gas.bufs(d),
                // Ghosts take their owners' velocities with the next refresh.
                ph: self.masked(gas),
                acc: if gas {
                    d.ptr(&self.acc)
                } else {
                    std::ptr::null_mut()
                },
                is_gas: gas as u32,
                cb: self.coupling_bufs(),
                out: std::ptr::null_mut(),
                loss: if heat {
                    d.opt(&ph.loss)
                } else {
                    std::ptr::null_mut()
                },
                p: p.dev,
            };
            d.run(R::COUPLING_RETURN, ph.n, &ra)?;
        }
        if c.damping.is_some() {
            // The gas's deviations first (every one before the dust reads them), then the
            // dust's damping, then the gas takes the momentum it took (one process: over ranks
            // the deviations and losses would need their own halos).
            for (ph, gas) in [(&self.gas, true), (&self.dust, false)] {
                let ra = th::ReturnArgs {
                    gas: self.gas.bufs(d),
                    ph: ph.bufs(d),
                    acc: std::ptr::null_mut(),
                    is_gas: gas as u32,
                    cb: c.bufs(d, &self.sm.kernel_at),
                    out: std::ptr::null_mut(),
                    loss: std::ptr::null_mut(),
                    p: p.dev,
                };
                d.run(R::COUPLING_DAMP, ph.n, &ra)?;
            }
            d.run(R::COUPLING_REACT, ng, &ca)?;
        }
        if let (true, Some(_)) = (heat, &c.heat) {
            // The heat sums the neighbours' losses.
            self.ghost_sync(&Refresh::COUPLING_RETURN)?;
        }
        let d = &self.d;
        let c = self.coupling.as_ref().expect("kernel coupling");
        if let (true, Some(h)) = (heat, &c.heat) {
            let ha = th::CouplingHeatArgs {
                couple: ca,
                loss_gas: d.opt(&self.gas.loss),
                loss_dust: d.opt(&self.dust.loss),
                heat: d.ptr(h),
            };
            d.run(R::COUPLING_HEAT, ng, &ha)?;
        }
        Ok(())
    }

    /// Velocity kick over `dt` from the accelerations in `acc` (A^n, or zero): ũ = u + dt·B for
    /// the dust, the drag pass over `dt` (cell or kernel coupling) and the particle velocity
    /// updates, or without dust v = v + dt·A. With `heat`, the drag heat per union cell is left
    /// in `cells.heat` for [`Self::energy_step`].
    pub(super) fn kick(
        &mut self,
        timers: &mut Timers,
        dt: f64,
        heat: bool,
    ) -> Result<(), StepError> {
        // The stage names are what summary.json lists as the run's pipeline.
        let drag = self.stages.drag;
        let pulled = self.phys.ext_dust.iter().any(|a| *a != 0.0) || self.phys.gravity.is_on();
        if pulled && self.dust.n > 0 {
            let a = th::DustAccelArgs {
                ph: self.dust.bufs(&self.d),
                p: self.params(dt)?.dev,
            };
            timers.time("external dust acceleration (ũ = u + τB)", || {
                self.d.run(R::DUST_ACCEL, self.dust.n, &a)
            })?;
        }
        if drag && self.coupling.is_some() {
            // The kernel coupling updates the velocities (and spreads the heat) itself.
            let name = if heat {
                "IDIC drag, kernel coupling (gas particles as cells) + drag heating"
            } else {
                "IDIC drag, kernel coupling (gas particles as cells)"
            };
            return timers.time(name, || self.kernel_coupling(dt, heat));
        }
        let name = match (drag, self.stages.explicit_drag) {
            (false, _) => "gas velocities (v + τA, no dust)",
            (true, false) => "IDIC drag (cell sums, implicit cell solve, particle velocities)",
            (true, true) => "explicit drag (cell means, forward-Euler particle velocities)",
        };
        timers.time(name, || -> Result<(), GpuError> {
            if drag {
                self.cell_step(dt, false)?;
            }
            let d = &self.d;
            let p = self.params(dt)?;
            let ga = th::KickArgs {
                ph: self.gas.bufs(d),
                acc: d.ptr(&self.acc),
                drag: drag as u32,
                cells: self.cells.bufs(d),
                loss: if heat {
                    d.opt(&self.gas.loss)
                } else {
                    std::ptr::null_mut()
                },
                p: p.dev,
            };
            d.run(R::GAS_KICK, self.gas.n, &ga)?;
            if drag {
                let da = th::KickArgs {
                    ph: self.dust.bufs(d),
                    acc: std::ptr::null(),
                    loss: if heat {
                        d.opt(&self.dust.loss)
                    } else {
                        std::ptr::null_mut()
                    },
                    ..ga
                };
                d.run(R::DUST_KICK, self.dust.n, &da)?;
            }
            Ok(())
        })?;
        if drag && heat {
            let d = &self.d;
            let ha = th::HeatArgs {
                gas: self.gas.bufs(d),
                dust: self.dust.bufs(d),
                loss_gas: d.opt(&self.gas.loss),
                loss_dust: d.opt(&self.dust.loss),
                cells: self.cells.bufs(d),
                heat: d.ptr(&self.cells.heat),
                p: self.params(dt)?.dev,
            };
            timers.time("drag heating (the kinetic energy lost, to the gas)", || {
                d.run(R::HEAT, self.cells.ukey.len, &ha)
            })?;
        }
        Ok(())
    }

    /// Stopping time of every dust particle (its cell's t_k*; +∞ where uncoupled).
    pub fn dust_stopping_times(&mut self, state: &mut State) -> Result<Vec<Vec<f64>>, StepError> {
        if state.dust.is_empty() {
            return Ok(Vec::new());
        }
        self.refresh_dust_density(state)?;
        if self.coupling.is_some() {
            return self.kernel_stopping_times();
        }
        self.cell_step(0.0, true)?;
        let d = &self.d;
        let p = self.params(0.0)?;
        let (nb, ks) = (p.stride(), self.grid.total_cells() + 1);
        let sparse = self.cells.sparse;
        let ubidx = match sparse {
            Some(_) => Vec::new(),
            None => d.get(&self.cells.uidx, nb)?,
        };
        let nu = sparse.map_or_else(|| ubidx[nb - 1] as usize, |n| n as usize);
        let ukey = d.get(&self.cells.ukey, nu)?;
        let nf = self.dust.groups;
        let ts = d.get_f64(&self.cells.t_stop, nu * nf)?;
        let keys = d.get(&self.dust.keys, self.dust.n)?;
        let sc = p.sub_cells();
        Ok((0..nf)
            .map(|g| {
                (self.dust.off[g] as usize..self.dust.off[g + 1] as usize)
                    .map(|j| {
                        let k = keys[j] % ks;
                        let u = match sparse {
                            Some(_) => ukey.binary_search(&k).ok(),
                            None => th::union_index(&ubidx, &ukey, sc, k),
                        };
                        ts[u.expect("a dust particle's cell is occupied") * nf + g]
                    })
                    .collect()
            })
            .collect())
    }

    /// Kernel coupling: the stopping time each dust particle feels (the CPU's
    /// the solve's t_s at the particle, spread back with the weights of the return).
    pub(super) fn kernel_stopping_times(&mut self) -> Result<Vec<Vec<f64>>, StepError> {
        self.coupling_norms()?;
        self.ghost_sync(&Refresh::COUPLING_NORMS)?;
        self.coupling_deposits()?;
        let d = &self.d;
        let p = self.params(0.0)?;
        let ca = th::CoupleArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            acc: d.ptr(&self.zero_acc),
            pres: d.ptr(&self.pres),
            cb: self.coupling_bufs(),
            p: p.dev,
        };
        d.run(R::COUPLING_SOLVE, self.gas.n, &ca)?;
        self.ghost_sync(&Refresh::COUPLING_SOLVE)?;
        let d = &self.d;
        let c = self.coupling.as_ref().expect("kernel coupling");
        let out: Buf<L, R> = d.buf(self.dust.n.max(1))?;
        let ra = th::ReturnArgs {
            gas: self.gas.bufs(d),
            ph: self.dust.bufs(d),
            acc: std::ptr::null_mut(),
            is_gas: 0,
            cb: c.bufs(d, &self.sm.kernel_at),
            out: d.ptr(&out),
            loss: std::ptr::null_mut(),
            p: p.dev,
        };
        d.run(R::COUPLING_TSTOP, self.dust.n, &ra)?;
        let ts = d.get_f64(&out, self.dust.n)?;
        Ok((0..self.dust.groups)
            .map(|g| ts[self.dust.off[g] as usize..self.dust.off[g + 1] as usize].to_vec())
            .collect())
    }
}
