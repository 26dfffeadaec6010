//! The propagator: one step of the first-order scheme (method.md §3.6) or of the
//! kick–drift–kick leapfrog, as the sequence of the passes of the sibling modules.
use super::*;

impl<L: Launcher, R: Float> Engine<L, R> {
    pub(super) fn drift(&self, ph: &PhaseBuffers<L, R>, tau: f64) -> Result<(), GpuError> {
        ph.stale_list();
        let a = th::DriftArgs {
            ph: ph.bufs(&self.d),
            p: self.params(tau)?.dev,
        };
        self.d.run(R::DRIFT, ph.n, &a)
    }

    /// e ← e + dt·ė (+ the drag heat left by the last [`Self::kick`] when `heat`).
    pub(super) fn energy_step(&self, dt: f64, heat: bool) -> Result<(), GpuError> {
        let d = &self.d;
        if let (Some(e), Some(dedt)) = (&self.e, &self.dedt) {
            let a = th::EnergyArgs {
                gas: self.gas.bufs(d),
                e: d.ptr(e),
                dedt: d.ptr(dedt),
                heat: match (heat, &self.coupling) {
                    (false, _) => std::ptr::null_mut(),
                    (true, Some(c)) => d.opt(&c.heat),
                    (true, None) => d.ptr(&self.cells.heat),
                },
                heat_per_particle: self.coupling.is_some() as u32,
                cells: self.cells.bufs(d),
                p: self.params(dt)?.dev,
            };
            d.run(R::ENERGY, self.gas.n, &a)?;
        }
        Ok(())
    }

    /// The layer after the drift: grid rebuild and sort, `before_density`, the gas density
    /// and EOS, and the dust densities where the drag needs them every step.
    pub(super) fn new_layer(
        &mut self,
        timers: &mut Timers,
        tau: f64,
        before_density: impl FnOnce(&mut Self) -> Result<(), GpuError>,
    ) -> Result<(), StepError> {
        timers.time("grid rebuild + sort", || self.regrid())?;
        self.resorted = true;
        before_density(self)?;
        let name = if self.stages.variable_h {
            "gas h and density (variable h, Newton–Raphson) + EOS"
        } else if self.stages.continuity_density {
            "gas density (continuity equation) + EOS"
        } else {
            "gas density + EOS"
        };
        timers.time(name, || self.gas_density_eos(Some(tau)))?;
        self.dust_density_fresh = false;
        if self.stages.dust_density_each_step {
            let name = if self.stages.variable_h {
                "dust density (variable h)"
            } else {
                "dust density"
            };
            timers.time(name, || self.dust_density())?;
        }
        // The leapfrog's predicted kick reads the cell-mates' new densities.
        self.ghost_sync(&Refresh::NEW_LAYER)
    }

    /// Advance one step of size τ from layer n (forces already computed at layer n).
    pub fn advance(&mut self, state: &mut State, tau: f64) -> Result<(), StepError> {
        let mut timers = std::mem::take(&mut self.timers);
        self.resorted = false;
        let r = if self.stages.kdk {
            self.advance_kdk(&mut timers, tau)
        } else {
            self.advance_first_order(&mut timers, tau)
        };
        self.timers = timers;
        r?;
        state.t += tau;
        state.step += 1;
        self.step = state.step;
        self.t = state.t;
        self.check(state)
    }

    pub(super) fn advance_first_order(
        &mut self,
        timers: &mut Timers,
        tau: f64,
    ) -> Result<(), StepError> {
        // The authors' update drifts with v^n (method.md §3.3): kept aside across the kick.
        let old = self.phys.position_update == PositionUpdate::Old;
        if old {
            self.d.copy(&self.gas.v, &self.kdk.v_save, self.gas.n)?;
            self.d.copy(&self.dust.v, &self.kdk.u_save, self.dust.n)?;
        }
        let heat = self.stages.heating && self.stages.drag;
        self.kick(timers, tau, heat)?;
        let name = match (self.e.is_some(), old) {
            (false, false) => "positions (x + τv^{n+1})",
            (true, false) => "positions (x + τv^{n+1}) + gas energy",
            (false, true) => "positions (x + τv^n, the authors' update)",
            (true, true) => "positions (x + τv^n, the authors' update) + gas energy",
        };
        timers.time(name, || -> Result<(), GpuError> {
            if old {
                std::mem::swap(&mut self.gas.v, &mut self.kdk.v_save);
                std::mem::swap(&mut self.dust.v, &mut self.kdk.u_save);
            }
            self.drift(&self.gas, tau)?;
            self.drift(&self.dust, tau)?;
            if old {
                std::mem::swap(&mut self.gas.v, &mut self.kdk.v_save);
                std::mem::swap(&mut self.dust.v, &mut self.kdk.u_save);
            }
            self.energy_step(tau, heat)
        })?;
        self.ghost_sync(&Refresh::DRIFT)?;
        self.new_layer(timers, tau, |_| Ok(()))
    }

    /// Kick–drift–kick leapfrog (Phantom's): half kick (forces + drag over
    /// τ/2), drift with v^{n+1/2}, the new layer with predicted e*, predicted v*, u* (a τ/2 kick
    /// with the old forces and the drag at the new layer), forces there, then the closing half
    /// kick from v^{n+1/2} with the new forces, which are kept for the next step.
    pub(super) fn advance_kdk(&mut self, timers: &mut Timers, tau: f64) -> Result<(), StepError> {
        let half = 0.5 * tau;
        let heat = self.stages.heating && self.stages.drag;
        self.kick(timers, half, heat)?;
        let name = if self.e.is_some() {
            "leapfrog: gas energy half step + positions (x + τv^{n+1/2})"
        } else {
            "leapfrog: positions (x + τv^{n+1/2})"
        };
        timers.time(name, || -> Result<(), GpuError> {
            self.energy_step(half, heat)?;
            self.drift(&self.gas, tau)?;
            self.drift(&self.dust, tau)
        })?;
        self.ghost_sync(&Refresh::DRIFT)?;
        // The sort carries A^n and ė^n (kdk sorts them with the gas): e* = e^{n+1/2} + τ/2 ė^n
        // sets the pressure of the new layer.
        self.new_layer(timers, tau, |eng| {
            if let (Some(e), Some(save)) = (&eng.e, &eng.kdk.e_save) {
                eng.d.copy(e, save, eng.gas.n)?;
            }
            eng.energy_step(half, false)
        })?;
        let d = &self.d;
        d.copy(&self.gas.v, &self.kdk.v_save, self.gas.n)?;
        d.copy(&self.dust.v, &self.kdk.u_save, self.dust.n)?;
        // Predicted velocities v*, u* (drag included: for stiff drag the undragged prediction
        // would be off by O(1)), timed apart from the two half kicks.
        let mut pred = timers.empty_like();
        self.kick(&mut pred, half, false)?;
        self.ghost_sync(&Refresh::PREDICTOR)?;
        let t_pred: f64 = pred.entries().iter().map(|e| e.1).sum();
        timers.add(
            "leapfrog: predicted v*, u* at the new layer (half kick + drag)",
            t_pred,
        );
        self.kdk.closing = None;
        let f1 = self.compute_forces(timers)?;
        std::mem::swap(&mut self.gas.v, &mut self.kdk.v_save);
        std::mem::swap(&mut self.dust.v, &mut self.kdk.u_save);
        if let (Some(e), Some(save)) = (&mut self.e, &mut self.kdk.e_save) {
            std::mem::swap(e, save);
        }
        self.kick(timers, half, heat)?;
        if self.e.is_some() {
            timers.time("leapfrog: closing gas energy half step + EOS", || {
                self.energy_step(half, heat)?;
                self.eos()
            })?;
        }
        self.kdk.closing = Some(f1);
        self.ghost_sync(&Refresh::CLOSING)
    }
}
