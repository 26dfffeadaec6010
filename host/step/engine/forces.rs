//! The gas forces at a layer: pressure (+ artificial viscosity), with the standard, grad-h or
//! IAD gradient (method.md §2), and the time-step maxima.
use super::*;

impl<L: Launcher, R: Float> Engine<L, R> {
    /// Non-drag gas accelerations (kept on the device) and the time-step maxima. Under the
    /// leapfrog, the previous step's closing forces (already on the device).
    pub fn forces(&mut self) -> Result<Forces, StepError> {
        if let (true, Some(f)) = (self.stages.kdk, self.kdk.closing) {
            return Ok(f);
        }
        let mut timers = std::mem::take(&mut self.timers);
        let f = self.compute_forces(&mut timers);
        self.timers = timers;
        f
    }

    /// The gas accelerations at the current layer, downloaded (diagnostics and tests).
    pub fn accelerations(&mut self) -> Result<Vec<V3>, StepError> {
        let mut timers = std::mem::take(&mut self.timers);
        let r = self.compute_forces(&mut timers);
        self.timers = timers;
        r?;
        Ok(self.d.get_v3(&self.acc, self.gas.n)?)
    }

    /// Each gas particle's |A| and signal speed at the current layer (the time bins' census,
    /// [`crate::analysis::bins`]): under the leapfrog its closing forces as they stand (the next
    /// step's; recomputing them from v^{n+1} instead of v* would change the run), else the
    /// forces computed here, as the next step will compute them.
    pub fn particle_limits(&mut self) -> Result<(Vec<V3>, Vec<f64>), StepError> {
        let n = self.gas.n;
        if let (true, Some(_), Some(vsig)) = (self.stages.kdk, self.kdk.closing, &self.kdk.vsig) {
            return Ok((self.d.get_v3(&self.acc, n)?, self.d.get_f64(vsig, n)?));
        }
        let kept = self.kdk.vsig.is_some();
        if !kept {
            self.kdk.vsig = Some(self.d.buf(n.max(1))?);
        }
        let acc = self.accelerations();
        let vsig = match &self.kdk.vsig {
            Some(v) => self.d.get_f64(v, n).map_err(StepError::from),
            None => unreachable!("set above"),
        };
        if !kept {
            self.kdk.vsig = None;
        }
        Ok((acc?, vsig?))
    }

    /// The gas particles that set the time step: the largest |A| (force limit) and the largest
    /// sound speed (CFL limit), with their ids and positions, for a collapsing step's message.
    pub fn dt_culprits(&mut self) -> Result<String, StepError> {
        let acc = self.accelerations()?;
        let d = &self.d;
        let n = self.gas.n;
        let (cs, id, x) = (
            d.get_f64(&self.cs, n)?,
            d.get(&self.gas.id, n)?,
            d.get(&self.gas.x, n)?,
        );
        let argmax = |v: &dyn Fn(usize) -> f64| (0..n).max_by(|&a, &b| v(a).total_cmp(&v(b)));
        let amag = |i: usize| acc[i].iter().map(|a| a * a).sum::<f64>().sqrt();
        let mut out = Vec::new();
        if let Some(i) = argmax(&amag) {
            out.push(format!(
                "largest |A| = {:e} at gas particle id {} (x = {:?})",
                amag(i),
                id[i],
                x[i]
            ));
        }
        if let Some(i) = argmax(&|i| cs[i]) {
            out.push(format!(
                "largest c_s = {:e} at gas particle id {} (x = {:?})",
                cs[i], id[i], x[i]
            ));
        }
        Ok(out.join("; "))
    }

    /// Set the gas forces of the coming step to zero (A = 0, ė = 0): the step that follows is
    /// the drag pass, the drift and the new layer alone.
    pub fn zero_forces(&mut self) -> Result<(), StepError> {
        let d = &self.d;
        d.zeroed(&mut self.acc, self.gas.n)?;
        if let Some(e) = &mut self.dedt {
            d.zeroed(e, self.gas.n)?;
        }
        self.kdk.closing = None;
        Ok(())
    }

    /// The forces at the state on the device.
    pub(super) fn compute_forces(&mut self, timers: &mut Timers) -> Result<Forces, StepError> {
        let d = &self.d;
        d.put(&mut self.limits, &[0, 0, 0])?;
        let p = self.params(0.0)?;
        let mode = if self.stages.iad {
            2
        } else {
            u32::from(self.stages.variable_h)
        };
        if mode != 0 {
            let a = th::PrepArgs {
                gas: self.gas.bufs(d),
                h: d.opt(&self.sm.gas_h),
                // IAD's pressure term is p/ρ² (no grad-h factor).
                omega: if mode == 1 {
                    d.opt(&self.sm.gas_omega)
                } else {
                    std::ptr::null_mut()
                },
                pres: d.ptr(&self.pres),
                kernel_at: d.ptr(&self.sm.kernel_at),
                pt: d.ptr(&self.sm.pt),
                p: p.dev,
            };
            d.run(R::FORCE_PREP, self.gas.n, &a)?;
        }
        if mode == 2 {
            let a = th::IadArgs {
                gas: self.gas.bufs(d),
                kernel_at: d.ptr(&self.sm.kernel_at),
                iad: d.ptr(&self.sm.iad),
                p: p.dev,
            };
            timers.time("gas IAD matrices (Garcia-Senz et al. 2012)", || {
                d.run(R::IAD_MATRIX, self.gas.n, &a)
            })?;
            // The forces read the neighbours' matrices.
            self.ghost_sync(&Refresh::IAD_MATRICES)?;
        }
        let d = &self.d;
        let a = th::ForcesArgs {
            gas: self.masked(true),
            pres: d.ptr(&self.pres),
            c: d.ptr(&self.cs),
            acc: d.ptr(&self.acc),
            dedt: d.opt(&self.dedt),
            limits: d.ptr(&self.limits),
            mode,
            kernel_at: d.ptr(&self.sm.kernel_at),
            pt: d.ptr(&self.sm.pt),
            iad: d.ptr(&self.sm.iad),
            vsig: d.opt(&self.kdk.vsig),
            own_h: u32::from(self.stages.variable_h),
            p: p.dev,
        };
        let name = match (self.phys.av.is_some(), mode) {
            (false, 0) => "gas forces (pressure)",
            (true, 0) => "gas forces (pressure + artificial viscosity)",
            (false, 1) => "gas forces (pressure, grad-h)",
            (true, 1) => "gas forces (pressure + artificial viscosity, grad-h)",
            (false, _) => "gas forces (pressure, IAD gradient)",
            (true, _) => "gas forces (pressure + artificial viscosity, IAD gradient)",
        };
        timers.time(name, || d.run(R::FORCES, self.gas.n, &a))?;
        if self.phys.gravity.is_on() && self.dust.n > 0 {
            // The point mass pulls the dust too: its |B| joins the force limit.
            let a = th::DustLimitArgs {
                acc: th::DustAccelArgs {
                    ph: self.dust.bufs(d),
                    p: p.dev,
                },
                limits: d.ptr(&self.limits),
            };
            d.run(R::DUST_ACCEL_LIMIT, self.dust.n, &a)?;
        }
        // The drag's cell sums read the cell-mates' accelerations.
        self.ghost_sync(&Refresh::FORCES)?;
        let l = self.d.get(&self.limits, 3)?;
        let dec = |b: u64| if b == 0 { 0.0 } else { from_ordered_bits(b) };
        Ok(Forces {
            vsig_max: dec(l[0]),
            acc_max: dec(l[1]),
            damp_rate_max: dec(l[2]),
        })
    }
}
