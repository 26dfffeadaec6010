//! Ghost particles over MPI ranks (docs/scaling.md, "A thin halo"): their masks and the
//! refresh of their values from their owners between the step's neighbour passes.
use super::*;

/// A per-particle field the halo can move (a buffer of the engine, gas or dust).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Field {
    Position,
    Velocity,
    Mass,
    Density,
    /// The kinetic energy the drag took (drag heating).
    KineticLoss,
    Pressure,
    SoundSpeed,
    Energy,
    Acceleration,
    EnergyRate,
    /// The leapfrog's signal speeds (its closing forces' v_sig).
    SignalSpeed,
    /// The velocities kept across a kick (the leapfrog; the authors' position update).
    SavedVelocity,
    SavedEnergy,
    SmoothingLength,
    Omega,
    /// Per-particle kernel constants (variable h, IAD) and the pressure term p/(Ωρ²).
    KernelAt,
    PressureTerm,
    IadMatrix,
    /// The kernel coupling's normaliser S_q, its increments and stopping times, its heat.
    CouplingNorm,
    GasIncrement,
    DustIncrement,
    CouplingStoppingTime,
    CouplingHeat,
}

impl Field {
    pub(super) const ALL: &'static [Field] = &[
        Field::Position,
        Field::Velocity,
        Field::Mass,
        Field::Density,
        Field::KineticLoss,
        Field::Pressure,
        Field::SoundSpeed,
        Field::Energy,
        Field::Acceleration,
        Field::EnergyRate,
        Field::SignalSpeed,
        Field::SavedVelocity,
        Field::SavedEnergy,
        Field::SmoothingLength,
        Field::Omega,
        Field::KernelAt,
        Field::PressureTerm,
        Field::IadMatrix,
        Field::CouplingNorm,
        Field::GasIncrement,
        Field::DustIncrement,
        Field::CouplingStoppingTime,
        Field::CouplingHeat,
    ];
}

/// A halo refresh between two of the step's passes: the fields the passes since the last
/// refresh wrote (every rank steps its engine from its owners' values; a refresh moves what
/// changed since). A field left out that a later pass reads is caught by `DUSTSPH_HALO_CHECK`
/// (tests/mpi.rs runs every scene with it).
pub(super) struct Refresh {
    pub name: &'static str,
    pub fields: &'static [Field],
}

use Field::*;

impl Refresh {
    /// When the ghosts are set: everything.
    pub(super) const EVERYTHING: Refresh = Refresh {
        name: "at the start",
        fields: Field::ALL,
    };
    /// The IAD matrices and the per-particle kernels the forces read.
    pub(super) const IAD_MATRICES: Refresh = Refresh {
        name: "after the IAD matrices",
        fields: &[KernelAt, PressureTerm, IadMatrix],
    };
    /// The forces the drag's cell sums read (and the kernels of a variable-h force pass).
    pub(super) const FORCES: Refresh = Refresh {
        name: "after the forces",
        fields: &[
            KernelAt,
            PressureTerm,
            Acceleration,
            EnergyRate,
            SignalSpeed,
        ],
    };
    /// The kernel coupling's normalisers (and the dust's external kick before them) its solve
    /// reads.
    pub(super) const COUPLING_NORMS: Refresh = Refresh {
        name: "after the kernel coupling's normalisers",
        fields: &[Velocity, KernelAt, PressureTerm, CouplingNorm],
    };
    /// The kernel coupling's solve on every gas particle, which the return reads.
    pub(super) const COUPLING_SOLVE: Refresh = Refresh {
        name: "after the kernel coupling's solve",
        fields: &[GasIncrement, DustIncrement, CouplingStoppingTime],
    };
    /// The kernel coupling's return (velocities, losses), which its heat sums read.
    pub(super) const COUPLING_RETURN: Refresh = Refresh {
        name: "after the kernel coupling's return",
        fields: &[Velocity, KineticLoss],
    };
    /// The kick, the drift and the energy update.
    pub(super) const DRIFT: Refresh = Refresh {
        name: "after the drift",
        fields: &[
            Position,
            Velocity,
            KineticLoss,
            Energy,
            SavedVelocity,
            CouplingHeat,
        ],
    };
    /// The new layer's densities, h, pressures (and the leapfrog's predicted energy).
    pub(super) const NEW_LAYER: Refresh = Refresh {
        name: "at the end of the new layer",
        fields: &[
            Density,
            Pressure,
            SoundSpeed,
            SmoothingLength,
            Omega,
            Energy,
            SavedEnergy,
        ],
    };
    /// The leapfrog's closing kick, energy half step and EOS, which the next step's first kick
    /// reads (the resident engine over ranks keeps its ghosts across steps).
    pub(super) const CLOSING: Refresh = Refresh {
        name: "after the leapfrog's closing kick",
        fields: &[
            Velocity,
            KineticLoss,
            Energy,
            Pressure,
            SoundSpeed,
            CouplingHeat,
        ],
    };
    /// The dust densities an output computes, which its stopping times' cell sums read.
    pub(super) const OUTPUT_DENSITY: Refresh = Refresh {
        name: "after an output's dust densities",
        fields: &[Density],
    };
    /// The leapfrog's predicted velocities, which its forces at the new layer read.
    pub(super) const PREDICTOR: Refresh = Refresh {
        name: "after the leapfrog's predictor",
        fields: &[Velocity, SavedVelocity],
    };
}

/// Ghost particles: copies of particles another MPI rank owns, within one interaction reach of
/// this rank's own (docs/scaling.md, "A thin halo"). Between the step's neighbour passes the
/// engine hands every particle's per-particle values to [`GhostSync::refresh`], which writes
/// the owners' values into the ghosts' rows; the ghosts keep their density, h and forces out
/// of those passes (their neighbourhoods are cut off at the halo's edge) and out of the step's
/// maxima.
pub trait GhostSync: Send {
    /// After each sort: every slot's key per phase table (gas, then the dust), in the new
    /// order; the refreshes until the next sort read and write rows by these slots.
    fn reorder(&mut self, slots: &[Vec<(u64, u64)>]) -> Result<(), String>;
    /// After a later sort of the same particles: slot i of table k moved to `new_of_old[k][i]`.
    fn permute(&mut self, new_of_old: &[Vec<u32>]) -> Result<(), String>;
    /// Overwrite the ghosts' rows (gas first, then the dust) with their owners' (collective).
    fn refresh(&mut self, tables: &mut [GhostRows]) -> Result<(), String>;
}

/// One phase's particles as rows of bytes, in the slot order of the last
/// [`GhostSync::reorder`]: row i is `data[i * row .. (i + 1) * row]`, every per-particle
/// buffer's value of the refresh's fields.
pub struct GhostRows {
    pub row: usize,
    pub data: Vec<u8>,
}

/// The ghosts of an engine: the refresh, the ghosts' keys, and per phase a mask (fixed or ghost)
/// that the density, h and force passes take in place of `fixed`.
pub(super) struct Ghosts<L: Launcher> {
    pub(super) sync: Box<dyn GhostSync>,
    pub(super) keys: crate::particles::KeySet,
    pub(super) mask: [Option<Buf<L, u8>>; 2],
    /// 1 for a ghost only (not a wall), per phase: the explicit drag limit's cells.
    pub(super) only: [Option<Buf<L, u8>>; 2],
    /// The same flags on the host (the rank's own particles are those without).
    pub(super) host_only: [Vec<u8>; 2],
    /// The flags and the sync's slots were found by key (once, when the ghosts were set):
    /// after each sort they follow its permutation.
    pub(super) keyed: bool,
    /// `DUSTSPH_HALO_CHECK` was set when the ghosts were (read once, not at every refresh).
    pub(super) check: bool,
    /// Per phase, each slot's position when the ghosts were set (following the sorts, as
    /// the flags do): the motion since ([`Engine::owned_motion`]).
    pub(super) anchor: [Vec<V3>; 2],
}

/// How far a rank's own particles moved since its ghosts were set ([`Engine::owned_motion`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OwnedMotion {
    /// The largest displacement (minimum image on periodic axes).
    pub largest: f64,
    /// The displacements' bounding box, per axis.
    pub lo: [f64; 3],
    pub hi: [f64; 3],
    /// The largest solved h (0 where h is fixed).
    pub h_max: f64,
}

impl<L: Launcher, R: Float> Engine<L, R> {
    /// A phase's buffers for the density, h and force passes, where ghosts count as fixed
    /// (they keep their values, and stay out of the maxima, until their owners' arrive).
    pub(super) fn masked(&self, gas: bool) -> PhaseBufs<R> {
        let ph = if gas { &self.gas } else { &self.dust };
        let mut b = ph.bufs(&self.d);
        if let Some(m) = self
            .ghosts
            .as_ref()
            .and_then(|g| g.mask[!gas as usize].as_ref())
        {
            b.fixed = self.d.ptr(m);
        }
        b
    }

    /// Make particles ghosts (`keys`: phase 0 gas, 1 + k dust fraction k; id) refreshed by
    /// `sync` between the step's neighbour passes, and refresh them now.
    pub fn set_ghosts(
        &mut self,
        sync: Box<dyn GhostSync>,
        keys: crate::particles::KeySet,
    ) -> Result<(), StepError> {
        if self.phys.damp_dispersion {
            return Err(StepError::Unsupported(
                "idic.dispersion = \"damped\" runs on one process (its deviations and losses \
                 have no halo refresh yet): run without mpirun or set it to \"kept\""
                    .into(),
            ));
        }
        self.ghosts = Some(Ghosts {
            sync,
            keys,
            mask: [None, None],
            only: [None, None],
            host_only: [Vec::new(), Vec::new()],
            keyed: false,
            check: std::env::var_os("DUSTSPH_HALO_CHECK").is_some(),
            anchor: [Vec::new(), Vec::new()],
        });
        self.ghost_masks()?;
        let anchor = [
            self.d.get(&self.gas.x, self.gas.n)?,
            self.d.get(&self.dust.x, self.dust.n)?,
        ];
        if let Some(g) = &mut self.ghosts {
            g.anchor = anchor;
        }
        self.ghost_sync(&Refresh::EVERYTHING)
    }

    /// The ghost flags and the sync's slots after a sort of the same particles: moved by the
    /// sort's permutation (slot i now holds what slot perm[i] held), without a key lookup.
    fn permute_ghosts(&mut self) -> Result<(), StepError> {
        let mut g = self.ghosts.take().expect("ghosts are set");
        let mut new_of_old = [Vec::new(), Vec::new()];
        for (k, gas) in [true, false].into_iter().enumerate() {
            let ph = if gas { &self.gas } else { &self.dust };
            if ph.n == 0 {
                continue;
            }
            let perm = self.d.get(&ph.perm, ph.n)?;
            let old = &g.host_only[k];
            let mut ghost = vec![0u8; ph.n];
            let mut new = vec![0u32; ph.n];
            for (i, &p) in perm.iter().enumerate() {
                ghost[i] = old[p as usize];
                new[p as usize] = i as u32;
            }
            let fixed = match &ph.fixed {
                Some(f) => self.d.get(f, ph.n)?,
                None => vec![0; ph.n],
            };
            let m: Vec<u8> = (ghost.iter().zip(&fixed)).map(|(&g, &f)| g | f).collect();
            g.mask[k] = Some(self.d.from(&m)?);
            g.only[k] = Some(self.d.from(&ghost)?);
            g.host_only[k] = ghost;
            if g.anchor[k].len() == ph.n {
                let old = std::mem::take(&mut g.anchor[k]);
                g.anchor[k] = perm.iter().map(|&p| old[p as usize]).collect();
            }
            new_of_old[k] = new;
        }
        let r = g.sync.permute(&new_of_old);
        self.ghosts = Some(g);
        r.map_err(|e| StepError::Blowup(format!("halo exchange: {e}")))
    }

    /// Per particle in the order [`Engine::sync`] writes the state (the gas, then each dust
    /// fraction), whether it is a ghost; `None` without ghosts.
    pub fn ghost_flags(&self) -> Option<Vec<bool>> {
        let g = self.ghosts.as_ref()?;
        let n = [self.gas.n, self.dust.n];
        Some(
            (0..2)
                .flat_map(|k| (0..n[k]).map(move |i| (k, i)))
                .map(|(k, i)| g.host_only[k].get(i).is_some_and(|&f| f != 0))
                .collect(),
        )
    }

    /// How far the particles that are not ghosts moved since the ghosts were set, and their
    /// largest solved h: what decides whether the halo still holds every neighbour
    /// (docs/scaling.md, "A resident engine"). `None` without ghosts.
    pub fn owned_motion(&self) -> Result<Option<OwnedMotion>, GpuError> {
        let Some(g) = &self.ghosts else {
            return Ok(None);
        };
        let domain = self.phys.domain;
        let mut m = OwnedMotion {
            largest: 0.0,
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
            h_max: 0.0,
        };
        for (k, gas) in [true, false].into_iter().enumerate() {
            let ph = if gas { &self.gas } else { &self.dust };
            if ph.n == 0 {
                continue;
            }
            let x = self.d.get(&ph.x, ph.n)?;
            let h = match (&self.sm.gas_h, gas) {
                (Some(h), true) => self.d.get_f64(h, ph.n)?,
                _ => Vec::new(),
            };
            for (i, (xi, ai)) in x.iter().zip(&g.anchor[k]).enumerate() {
                if g.host_only[k][i] != 0 {
                    continue;
                }
                let mut d2 = 0.0;
                for a in 0..3 {
                    let mut d = xi[a] - ai[a];
                    if let Some((_, len)) = domain.periodic[a] {
                        d = dustsph_device::update::min_image(d, len);
                    }
                    m.lo[a] = m.lo[a].min(d);
                    m.hi[a] = m.hi[a].max(d);
                    d2 += d * d;
                }
                m.largest = m.largest.max(d2.sqrt());
                if let Some(&hi) = h.get(i) {
                    m.h_max = m.h_max.max(hi);
                }
            }
        }
        Ok(Some(m))
    }

    /// Every slot's key (phase, id) of a phase, in the current order.
    pub(super) fn slot_keys(&self, gas: bool) -> Result<Vec<(u64, u64)>, GpuError> {
        let ph = if gas { &self.gas } else { &self.dust };
        let ids = self.d.get(&ph.id, ph.n)?;
        Ok(ids
            .iter()
            .enumerate()
            .map(|(i, &id)| {
                let phase = if gas {
                    0
                } else {
                    1 + (0..ph.groups)
                        .find(|&g| (i as u32) < ph.off[g + 1])
                        .unwrap_or(0) as u64
                };
                (phase, id)
            })
            .collect())
    }

    /// The slots' keys and the ghost masks in the current order (after each sort).
    pub(super) fn ghost_masks(&mut self) -> Result<(), StepError> {
        let Some(g) = &self.ghosts else {
            return Ok(());
        };
        if g.keyed {
            return self.permute_ghosts();
        }
        let mut masks: [Option<Buf<L, u8>>; 2] = [None, None];
        let mut only: [Option<Buf<L, u8>>; 2] = [None, None];
        let mut host_only = [Vec::new(), Vec::new()];
        let mut slots = [Vec::new(), Vec::new()];
        for (k, gas) in [true, false].into_iter().enumerate() {
            let ph = if gas { &self.gas } else { &self.dust };
            slots[k] = self.slot_keys(gas)?;
            if ph.n == 0 {
                continue;
            }
            let fixed = match &ph.fixed {
                Some(f) => self.d.get(f, ph.n)?,
                None => vec![0; ph.n],
            };
            let ghost: Vec<u8> = slots[k]
                .iter()
                .map(|key| g.keys.contains(key) as u8)
                .collect();
            let m: Vec<u8> = (ghost.iter().zip(&fixed)).map(|(&g, &f)| g | f).collect();
            masks[k] = Some(self.d.from(&m)?);
            only[k] = Some(self.d.from(&ghost)?);
            host_only[k] = ghost;
        }
        if let Some(g) = &mut self.ghosts {
            g.mask = masks;
            g.only = only;
            g.host_only = host_only;
            g.keyed = true;
            g.sync
                .reorder(&slots)
                .map_err(|e| StepError::Blowup(format!("halo exchange: {e}")))?;
        }
        Ok(())
    }

    /// Refresh the ghosts from their owners (a no-op without ghosts): the fields `refresh`
    /// names, as bytes, row by row. With `DUSTSPH_HALO_CHECK` set, a full refresh follows and
    /// any ghost value it changes (a field written since the last refresh and not named) stops
    /// the step, naming the refresh and the field.
    pub(super) fn ghost_sync(&mut self, refresh: &Refresh) -> Result<(), StepError> {
        if self.ghosts.is_none() {
            return Ok(());
        }
        self.exchange_rows(refresh.fields)?;
        let check = self.ghosts.as_ref().is_some_and(|g| g.check);
        if check && refresh.fields != Field::ALL {
            // After this step's sort, only the fields the sort carries have values that still
            // mean something until a pass writes them again.
            let live = if self.resorted {
                self.sorted_fields()
            } else {
                Field::ALL
            };
            let before = self.field_bytes(live)?;
            self.exchange_rows(Field::ALL)?;
            let after = self.field_bytes(live)?;
            if let Some((gas, f)) =
                (before.iter().zip(&after)).find_map(|(b, a)| (b.2 != a.2).then_some((b.0, b.1)))
            {
                return Err(StepError::Blowup(format!(
                    "halo check: the refresh {} left the ghosts' {f:?} ({}) stale",
                    refresh.name,
                    if gas { "gas" } else { "dust" }
                )));
            }
        }
        Ok(())
    }

    /// The fields the grid rebuild's sort carries with their particles.
    fn sorted_fields(&self) -> &'static [Field] {
        // The leapfrog's forces travel with their particles too (the last three).
        const CARRIED: &[Field] = &[
            Position,
            Velocity,
            Mass,
            Density,
            Pressure,
            SoundSpeed,
            Energy,
            SmoothingLength,
            Omega,
            Acceleration,
            EnergyRate,
            SignalSpeed,
        ];
        if self.stages.kdk {
            CARRIED
        } else {
            &CARRIED[..CARRIED.len() - 3]
        }
    }

    /// The `fields` of both phases as bytes (for the halo check).
    fn field_bytes(&mut self, fields: &[Field]) -> Result<Vec<(bool, Field, Vec<u8>)>, GpuError> {
        let mut out = Vec::new();
        for gas in [true, false] {
            for &f in fields {
                for (_, c) in self.ghost_columns(gas, None, &[f])? {
                    out.push((gas, f, c));
                }
            }
        }
        Ok(out)
    }

    /// Send the owners' values of `fields` and write them into the ghosts' rows (collective).
    fn exchange_rows(&mut self, fields: &[Field]) -> Result<(), StepError> {
        let mut rows = Vec::with_capacity(2);
        for gas in [true, false] {
            let n = if gas { self.gas.n } else { self.dust.n };
            let cols = self.ghost_columns(gas, None, fields)?;
            // The row's width from the pipeline, not from the data: the same on a rank
            // without particles of this phase as on its senders.
            let row: usize = cols.iter().map(|c| c.0).sum();
            let mut data = vec![0u8; n * row];
            let mut at = 0;
            for (w, c) in &cols {
                let w = *w;
                for i in 0..n {
                    data[i * row + at..i * row + at + w].copy_from_slice(&c[i * w..(i + 1) * w]);
                }
                at += w;
            }
            rows.push((row, data));
        }
        // The rows are in the slot order the sync learnt at the last sort (ghost_masks).
        let sync = &mut self.ghosts.as_mut().expect("ghosts are set").sync;
        let mut tables: Vec<GhostRows> = (rows.into_iter())
            .map(|(row, data)| GhostRows { row, data })
            .collect();
        sync.refresh(&mut tables)
            .map_err(|e| StepError::Blowup(format!("halo exchange: {e}")))?;
        let rows: Vec<(usize, Vec<u8>)> = tables.into_iter().map(|t| (t.row, t.data)).collect();
        for ((row, data), gas) in rows.iter().zip([true, false]) {
            self.ghost_columns(gas, Some((*row, data)), fields)?;
        }
        Ok(())
    }

    /// A phase's per-particle buffers of `fields` as byte columns with their bytes per
    /// particle (`put` = None), or written back from the rows of `put`; those this scene's
    /// pipeline does not use are left out.
    pub(super) fn ghost_columns(
        &mut self,
        gas: bool,
        put: Option<(usize, &[u8])>,
        fields: &[Field],
    ) -> Result<Vec<(usize, Vec<u8>)>, GpuError> {
        /// Buffer `b` with `per` values per particle, particle-major.
        pub(super) fn one<L: Launcher, T: Copy>(
            d: &Device<L>,
            b: Option<&mut Buf<L, T>>,
            n: usize,
            per: usize,
            put: Option<((usize, &[u8]), &mut usize)>,
            out: &mut Vec<(usize, Vec<u8>)>,
        ) -> Result<(), GpuError> {
            let Some(b) = b else { return Ok(()) };
            let w = std::mem::size_of::<T>() * per;
            if n == 0 || per == 0 {
                if put.is_none() {
                    out.push((w, Vec::new()));
                }
                return Ok(());
            }
            match put {
                None => {
                    let mut bytes = vec![0u8; n * w];
                    d.launcher.download(&b.mem, &mut bytes)?;
                    out.push((w, bytes));
                }
                Some(((row, data), at)) => {
                    let mut bytes = vec![0u8; n * w];
                    for i in 0..n {
                        bytes[i * w..(i + 1) * w]
                            .copy_from_slice(&data[i * row + *at..i * row + *at + w]);
                    }
                    *at += w;
                    d.launcher.upload(&mut b.mem, &bytes)?;
                }
            }
            Ok(())
        }
        let mut out = Vec::new();
        let mut at = 0usize;
        let d = &self.d;
        // Which buffers: by the scene's pipeline (the same on every rank), never by a length.
        let save = self.stages.kdk || self.phys.position_update == PositionUpdate::Old;
        let smooth = self.stages.variable_h || self.stages.iad;
        let iad = self.stages.iad;
        macro_rules! col {
            ($f:ident, $b:expr, $n:expr) => {
                col!($f, $b, $n, 1)
            };
            ($f:ident, $b:expr, $n:expr, $per:expr) => {
                if fields.contains(&Field::$f) {
                    one(d, $b, $n, $per, put.map(|t| (t, &mut at)), &mut out)?
                }
            };
        }
        let nf = self.dust.groups;
        if gas {
            let n = self.gas.n;
            col!(Position, Some(&mut self.gas.x), n);
            col!(Velocity, Some(&mut self.gas.v), n);
            col!(Mass, Some(&mut self.gas.m), n);
            col!(Density, Some(&mut self.gas.rho), n);
            col!(KineticLoss, self.gas.loss.as_mut(), n);
            col!(Pressure, Some(&mut self.pres), n);
            col!(SoundSpeed, Some(&mut self.cs), n);
            col!(Energy, self.e.as_mut(), n);
            col!(Acceleration, Some(&mut self.acc), n);
            col!(EnergyRate, self.dedt.as_mut(), n);
            col!(SignalSpeed, self.kdk.vsig.as_mut(), n);
            col!(SavedVelocity, save.then_some(&mut self.kdk.v_save), n);
            col!(SavedEnergy, self.kdk.e_save.as_mut(), n);
            col!(SmoothingLength, self.sm.gas_h.as_mut(), n);
            col!(Omega, self.sm.gas_omega.as_mut(), n);
            col!(KernelAt, smooth.then_some(&mut self.sm.kernel_at), n);
            col!(PressureTerm, smooth.then_some(&mut self.sm.pt), n);
            col!(IadMatrix, iad.then_some(&mut self.sm.iad), n);
            if let Some(c) = &mut self.coupling {
                col!(CouplingNorm, Some(&mut c.s_gas), n);
                col!(GasIncrement, Some(&mut c.dv), n);
                col!(DustIncrement, Some(&mut c.du), n, nf);
                col!(CouplingStoppingTime, Some(&mut c.t_stop), n, nf);
                col!(CouplingHeat, c.heat.as_mut(), n);
            }
        } else {
            let n = self.dust.n;
            col!(Position, Some(&mut self.dust.x), n);
            col!(Velocity, Some(&mut self.dust.v), n);
            col!(Mass, Some(&mut self.dust.m), n);
            col!(Density, Some(&mut self.dust.rho), n);
            col!(KineticLoss, self.dust.loss.as_mut(), n);
            col!(SavedVelocity, save.then_some(&mut self.kdk.u_save), n);
            if let Some(c) = &mut self.coupling {
                col!(CouplingNorm, Some(&mut c.s_dust), n);
            }
        }
        Ok(out)
    }
}
