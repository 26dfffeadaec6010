//! Densities: the gas's (summation, continuity or variable h by Newton–Raphson, method.md §2),
//! the EOS, and the dust fractions' densities.
use super::*;

impl<L: Launcher, R: Float> Engine<L, R> {
    pub(super) fn density(&self, gas: bool) -> Result<(), GpuError> {
        let a = th::DensityArgs {
            ph: self.masked(gas),
            p: self.params(0.0)?.dev,
        };
        let n = if gas { self.gas.n } else { self.dust.n };
        self.d.run(R::DENSITY, n, &a)
    }

    /// Variable h of the gas (`gas = true`, from its current h, or the reference h at the
    /// start) or of every dust fraction (from the h of its last density): h, ρ (and Ω) by Newton–Raphson.
    /// A particle whose h runs into the search radius widens the grid's reach (same cells and
    /// order) and the solve is repeated, as on the CPU.
    pub(super) fn solve_h(&mut self, gas: bool, step: u64, tol: f64) -> Result<(), StepError> {
        let hfact = self.phys.variable_h.expect("variable h");
        let eps = if std::mem::size_of::<R>() == 4 {
            f32::EPSILON as f64
        } else {
            f64::EPSILON
        };
        for attempt in 0..40 {
            let d = &self.d;
            d.put(&mut self.bad, &[u32::MAX])?;
            let ph = if gas { &self.gas } else { &self.dust };
            let a = th::HSolveArgs {
                ph: self.masked(gas),
                h0: match (&self.sm.gas_h, gas) {
                    (Some(h), true) => d.ptr(h),
                    _ => std::ptr::null(),
                },
                // The dust starts from its last density's h: one Newton pass a step instead of
                // two from the reference h (docs/performance.md).
                warm: (!gas) as u32,
                h: d.ptr(&self.sm.h_new),
                omega: if gas {
                    d.ptr(&self.sm.omega_new)
                } else {
                    std::ptr::null_mut()
                },
                iters: d.ptr(&self.sm.iters),
                bad: d.ptr(&self.bad),
                hfact: R::from_f64(hfact),
                h_max: R::from_f64(self.grid.geom.support / SUPPORT),
                // Not below a few roundings of R (f32: 1.2e-7), which a correction never beats.
                tol: R::from_f64(tol.max(16.0 * eps)),
                p: self.params(0.0)?.dev,
            };
            d.run(R::SOLVE_H, ph.n, &a)?;
            let bad = d.get(&self.bad, 1)?[0];
            if bad == u32::MAX {
                if gas {
                    // The solved h and Ω become the gas's; its old buffers become the next
                    // scratch (no allocation in the step, once both are of the scratch's size).
                    let len = self.sm.h_new.len;
                    for (cur, new) in [
                        (&mut self.sm.gas_h, &mut self.sm.h_new),
                        (&mut self.sm.gas_omega, &mut self.sm.omega_new),
                    ] {
                        let spare = match cur.take() {
                            Some(b) if b.len == len => b,
                            _ => d.buf(len)?,
                        };
                        *cur = Some(std::mem::replace(new, spare));
                    }
                }
                return Ok(());
            }
            let i = bad as usize;
            let iters = d.get(&self.sm.iters, i + 1)?[i];
            if iters < 30 && self.grid.geom.support < 1e300 {
                // 2 % at first (a grid barely too fine), then 25 %: a disc's tapered edge
                // (Σ → 0 at r_in) needs h several times the reference (method.md §D).
                let grow = if attempt < 10 { 1.02 } else { 1.25 };
                self.grid = self.grid.with_support(grow * self.grid.geom.support);
                self.reset_list()?;
                continue;
            }
            let ids = d.get(&ph.id, i + 1)?;
            let h = d.get_f64(&self.sm.h_new, i + 1)?[i];
            let what = ph.phase_name(gas, i);
            return Err(StepError::Blowup(format!(
                "step {step}: variable h did not converge for {what} particle id {} (h = {h:e})",
                ids[i]
            )));
        }
        Err(StepError::Blowup(format!(
            "step {step}: variable h of the {} outgrew every search radius",
            if gas { "gas" } else { "dust" }
        )))
    }

    /// Pressure and sound speed from the density (and energy).
    pub(super) fn eos(&self) -> Result<(), GpuError> {
        let d = &self.d;
        let a = th::EosArgs {
            rho: d.ptr(&self.gas.rho),
            e: d.opt(&self.e),
            pres: d.ptr(&self.pres),
            c: d.ptr(&self.cs),
            n: self.gas.n as u32,
            x: if self.phys.local_cs.on != 0 {
                d.ptr(&self.gas.x)
            } else {
                std::ptr::null()
            },
            p: self.params(0.0)?.dev,
        };
        d.run(R::EOS, self.gas.n, &a)
    }

    /// Gas density at the current (new) positions, then the EOS: variable h, summation, or the
    /// continuity equation ρ += τ dρ/dt. `tau` is `None` at start-up and on resume, where a
    /// resumed variable-h state and a continuity density are kept as they are (a resume continues bit for bit).
    pub(super) fn gas_density_eos(&mut self, tau: Option<f64>) -> Result<(), StepError> {
        if self.stages.variable_h {
            let resumed = tau.is_none() && self.sm.gas_h.is_some();
            if !resumed {
                self.solve_h(true, self.step, H_TOL)?;
            }
        } else if !self.stages.continuity_density {
            self.density(true)?;
        } else if let Some(tau) = tau {
            let a = th::DensityArgs {
                ph: self.gas.bufs(&self.d),
                p: self.params(tau)?.dev,
            };
            self.d.run(R::DENSITY_CONTINUITY, self.gas.n, &a)?;
        }
        Ok(self.eos()?)
    }

    pub(super) fn dust_density(&mut self) -> Result<(), StepError> {
        if !self.dust_density_fresh {
            if self.stages.variable_h && self.dust.n > 0 {
                let tol = if self.stages.dust_density_each_step {
                    H_TOL
                } else {
                    H_TOL_OUTPUT
                };
                self.solve_h(false, self.step, tol)?;
            } else {
                self.density(false)?;
            }
            self.dust_density_fresh = true;
        }
        Ok(())
    }
}
