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
/// engine packs the rows of the particles other ranks hold as ghosts and hands them to
/// [`GhostSync::refresh`], which returns the owners' rows of this rank's ghosts; the ghosts
/// keep their density, h and forces out of those passes (their neighbourhoods are cut off at
/// the halo's edge) and out of the step's maxima.
pub trait GhostSync: Send {
    /// After each sort: every slot's key per phase table (gas, then the dust), in the new
    /// order; the refreshes until the next sort read and write rows by these slots.
    fn reorder(&mut self, slots: &[Vec<(u64, u64)>]) -> Result<(), String>;
    /// After a later sort of the same particles: slot i of table k moved to `new_of_old[k][i]`.
    fn permute(&mut self, new_of_old: &[Vec<u32>]) -> Result<(), String>;
    /// The slots of table k (0 the gas, 1 the dust) whose rows each refresh sends, in the
    /// order it takes them (a slot held as a ghost by several ranks appears once per rank).
    fn send_slots(&self, table: usize) -> &[u32];
    /// The slots of table k that the rows each refresh returns overwrite, in their order.
    fn recv_slots(&self, table: usize) -> &[u32];
    /// Send `out[k]`, the rows of table k (`row[k]` bytes each, in [`GhostSync::send_slots`]
    /// order), to the ranks holding them as ghosts; into `back[k]`, the owners' rows of this
    /// rank's ghosts of table k, in [`GhostSync::recv_slots`] order (collective).
    fn refresh(
        &mut self,
        row: [usize; 2],
        out: [&[u8]; 2],
        back: &mut [Vec<u8>; 2],
    ) -> Result<(), String>;
    /// Free the buffers kept across refreshes (after a refresh of every field, which the
    /// named ones never reach).
    fn trim(&mut self) {}
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
    /// Per table, the sync's send and receive slots on the launcher (uploaded after each
    /// sort, not at each refresh), and the refresh's rows (grown as needed).
    pub(super) send_on: [Option<Buf<L, u32>>; 2],
    pub(super) recv_on: [Option<Buf<L, u32>>; 2],
    pub(super) rows: std::cell::RefCell<Option<Buf<L, u8>>>,
    /// The refresh's rows on the host, per table: those sent, and those come back.
    pub(super) host_rows: [[Vec<u8>; 2]; 2],
}

/// Bytes per element of a buffer.
fn elem_bytes<L: Launcher, T>(_: &Buf<L, T>) -> usize {
    std::mem::size_of::<T>()
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
    /// `sync` between the step's neighbour passes, and refresh them now unless `fresh` (the
    /// engine was built from their owners' values and computed none of its own).
    pub fn set_ghosts(
        &mut self,
        sync: Box<dyn GhostSync>,
        keys: crate::particles::KeySet,
        fresh: bool,
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
            check: crate::env::check("DUSTSPH_HALO_CHECK"),
            anchor: [Vec::new(), Vec::new()],
            send_on: [None, None],
            recv_on: [None, None],
            rows: Default::default(),
            host_rows: Default::default(),
        });
        self.ghost_masks()?;
        let anchor = [
            self.d.get(&self.gas.x, self.gas.n)?,
            self.d.get(&self.dust.x, self.dust.n)?,
        ];
        if let Some(g) = &mut self.ghosts {
            g.anchor = anchor;
        }
        if fresh {
            return Ok(());
        }
        self.ghost_sync(&Refresh::EVERYTHING)?;
        // Every field's rows are several times a named refresh's: kept, they would hold the
        // largest buffers of the run for as long as this engine lives.
        self.free_refresh_buffers();
        Ok(())
    }

    /// Free the buffers the ghost refreshes keep between them (the rows packed and received,
    /// the exchange's bytes); the next refresh allocates them again. After a refresh of every
    /// field, and before an output, whose gathered state would otherwise lie beside them.
    pub fn free_refresh_buffers(&mut self) {
        if let Some(g) = &mut self.ghosts {
            g.rows = Default::default();
            g.host_rows = Default::default();
            g.sync.trim();
        }
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
            // Into the flags' buffers in place, and the anchors permuted in place: a second
            // copy of each beside the first, at every sort, was part of a rank's peak.
            let d = &self.d;
            let upload = |b: &mut Option<Buf<L, u8>>, v: &[u8]| -> Result<(), GpuError> {
                match b {
                    Some(b) if b.len == v.len() => d.put(b, v),
                    _ => {
                        *b = Some(d.from(v)?);
                        Ok(())
                    }
                }
            };
            upload(&mut g.mask[k], &m)?;
            upload(&mut g.only[k], &ghost)?;
            g.host_only[k] = ghost;
            if g.anchor[k].len() == ph.n {
                permute_in_place(&mut g.anchor[k], &perm);
            }
            new_of_old[k] = new;
        }
        let r = g.sync.permute(&new_of_old);
        self.ghosts = Some(g);
        r.map_err(|e| StepError::Blowup(format!("halo exchange: {e}")))?;
        Ok(self.upload_slots()?)
    }

    /// The sync's slots (after a sort) onto the launcher, for the refreshes until the next.
    fn upload_slots(&mut self) -> Result<(), GpuError> {
        let Some(g) = &mut self.ghosts else {
            return Ok(());
        };
        for k in 0..2 {
            let up = |s: &[u32]| (!s.is_empty()).then(|| self.d.from(s)).transpose();
            g.send_on[k] = up(g.sync.send_slots(k))?;
            g.recv_on[k] = up(g.sync.recv_slots(k))?;
        }
        Ok(())
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

    /// Phase k's (0 the gas, 1 the dust) ghost flags on the launcher, null without ghosts:
    /// for the kernels that leave a cell of ghosts alone to its owners.
    pub(super) fn ghost_only(&self, k: usize) -> *const u8 {
        (self.ghosts.as_ref())
            .and_then(|g| g.only[k].as_ref())
            .map_or(std::ptr::null(), |b| self.d.ptr(b) as *const u8)
    }

    /// How far the particles that are not ghosts moved since the ghosts were set, and their
    /// largest solved h: what decides whether the halo still holds every neighbour
    /// (docs/scaling.md, "A resident engine"). `None` without ghosts. `each` sees every such
    /// particle's phase table (0 the gas, 1 the dust), position then and displacement since.
    pub fn owned_motion(
        &self,
        each: &mut dyn FnMut(usize, V3, V3),
    ) -> Result<Option<OwnedMotion>, GpuError> {
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
                let mut d = [0.0; 3];
                for a in 0..3 {
                    d[a] = xi[a] - ai[a];
                    if let Some((_, len)) = domain.periodic[a] {
                        d[a] = dustsph_device::update::min_image(d[a], len);
                    }
                    m.lo[a] = m.lo[a].min(d[a]);
                    m.hi[a] = m.hi[a].max(d[a]);
                }
                m.largest = m.largest.max(d.iter().map(|v| v * v).sum::<f64>().sqrt());
                each(k, *ai, d);
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
        Ok(self.upload_slots()?)
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
            let n = if gas { self.gas.n } else { self.dust.n };
            let every = (n > 0)
                .then(|| self.d.from(&(0..n as u32).collect::<Vec<_>>()))
                .transpose()?;
            for &f in fields {
                let mut rows = Vec::new();
                self.pack_rows(gas, &[f], (every.as_ref(), n), &mut rows)?;
                out.push((gas, f, rows));
            }
        }
        Ok(out)
    }

    /// Send the owners' values of `fields` and write them into the ghosts' rows (collective):
    /// only the rows that go out are packed, and only the ghosts' rows written, on the launcher.
    fn exchange_rows(&mut self, fields: &[Field]) -> Result<(), StepError> {
        // The host's rows, out and back, are kept across refreshes.
        let [mut out, mut back] = std::mem::take(&mut self.ghosts_mut().host_rows);
        let g = self.ghosts.as_ref().expect("ghosts are set");
        let sent = |k: usize| g.sync.send_slots(k).len();
        let [gas_out, dust_out] = &mut out;
        // The row's width from the pipeline, not from the data: the same on a rank without
        // particles of this phase as on its senders.
        let row = [
            self.pack_rows(true, fields, (g.send_on[0].as_ref(), sent(0)), gas_out)?,
            self.pack_rows(false, fields, (g.send_on[1].as_ref(), sent(1)), dust_out)?,
        ];
        let sync = &mut self.ghosts_mut().sync;
        (sync.refresh(row, [&out[0], &out[1]], &mut back))
            .map_err(|e| StepError::Blowup(format!("halo exchange: {e}")))?;
        let g = self.ghosts.as_ref().expect("ghosts are set");
        for (k, gas) in [true, false].into_iter().enumerate() {
            let n = g.sync.recv_slots(k).len();
            self.unpack_rows(gas, fields, (g.recv_on[k].as_ref(), n), row[k], &back[k])?;
        }
        self.ghosts_mut().host_rows = [out, back];
        Ok(())
    }

    fn ghosts_mut(&mut self) -> &mut Ghosts<L> {
        self.ghosts.as_mut().expect("ghosts are set")
    }

    /// The rows (`fields` of one phase, each row its particle's values in field order) of
    /// the `n` slots in `idx`, packed on the launcher into `out`: the row's bytes.
    fn pack_rows(
        &self,
        gas: bool,
        fields: &[Field],
        (idx, n): (Option<&Buf<L, u32>>, usize),
        out: &mut Vec<u8>,
    ) -> Result<usize, GpuError> {
        let cols = self.ghost_fields(gas, fields);
        let row: usize = cols.iter().map(|c| c.1).sum();
        out.clear();
        let Some(idx) = idx.filter(|_| n > 0 && row > 0) else {
            return Ok(row);
        };
        let rows = self.rows_scratch(n * row)?;
        let rows = rows.as_ref().expect("grown above");
        self.run_rows(kt::PACK_ROWS, &cols, idx, rows, n, row)?;
        self.d.get_into(rows, n * row, out)?;
        Ok(row)
    }

    /// Write the rows `data` (as [`Engine::pack_rows`] packs them, `row` bytes each) into
    /// the `fields` of one phase at the `n` slots in `idx`, on the launcher.
    fn unpack_rows(
        &self,
        gas: bool,
        fields: &[Field],
        (idx, n): (Option<&Buf<L, u32>>, usize),
        row: usize,
        data: &[u8],
    ) -> Result<(), GpuError> {
        let Some(idx) = idx.filter(|_| n > 0 && row > 0) else {
            return Ok(());
        };
        let cols = self.ghost_fields(gas, fields);
        let mut rows = self.rows_scratch(data.len())?;
        let rows = rows.as_mut().expect("grown above");
        self.d.put(rows, data)?;
        self.run_rows(kt::UNPACK_ROWS, &cols, idx, rows, n, row)
    }

    /// The refresh's rows buffer, at least `bytes` long (kept across refreshes).
    fn rows_scratch(
        &self,
        bytes: usize,
    ) -> Result<std::cell::RefMut<'_, Option<Buf<L, u8>>>, GpuError> {
        let g = self.ghosts.as_ref().expect("ghosts are set");
        let mut rows = g.rows.borrow_mut();
        if rows.as_ref().is_none_or(|b| b.len < bytes) {
            *rows = Some(self.d.buf(bytes + bytes / 2)?);
        }
        Ok(rows)
    }

    /// One launch of `k` per field column.
    fn run_rows(
        &self,
        k: Kernel<th::RowsArgs>,
        cols: &[(*mut u8, usize)],
        idx: &Buf<L, u32>,
        rows: &Buf<L, u8>,
        n: usize,
        row: usize,
    ) -> Result<(), GpuError> {
        let d = &self.d;
        let mut offset = 0;
        for &(field, width) in cols {
            let a = th::RowsArgs {
                field,
                rows: d.ptr(rows),
                slots: d.ptr(idx),
                n: n as u32,
                width: width as u32,
                stride: row as u32,
                offset: offset as u32,
            };
            d.run(k, n, &a)?;
            offset += width;
        }
        Ok(())
    }

    /// A phase's per-particle buffers of `fields`, as (address, bytes per particle), in the
    /// rows' column order; those this scene's pipeline does not use are left out.
    pub(super) fn ghost_fields(&self, gas: bool, fields: &[Field]) -> Vec<(*mut u8, usize)> {
        let mut out = Vec::new();
        let d = &self.d;
        let mut one = |ptr: *mut u8, w: usize| out.push((ptr, w));
        // Which buffers: by the scene's pipeline (the same on every rank), never by a length.
        let save = self.stages.kdk || self.phys.position_update == PositionUpdate::Old;
        let smooth = self.stages.variable_h || self.stages.iad;
        let iad = self.stages.iad;
        macro_rules! col {
            ($f:ident, $b:expr) => {
                col!($f, $b, 1)
            };
            ($f:ident, $b:expr, $per:expr) => {
                if fields.contains(&Field::$f) {
                    if let Some(b) = $b {
                        one(d.ptr(b) as *mut u8, elem_bytes(b) * $per);
                    }
                }
            };
        }
        let nf = self.dust.groups;
        if gas {
            col!(Position, Some(&self.gas.x));
            col!(Velocity, Some(&self.gas.v));
            col!(Mass, Some(&self.gas.m));
            col!(Density, Some(&self.gas.rho));
            col!(KineticLoss, self.gas.loss.as_ref());
            col!(Pressure, Some(&self.pres));
            col!(SoundSpeed, Some(&self.cs));
            col!(Energy, self.e.as_ref());
            col!(Acceleration, Some(&self.acc));
            col!(EnergyRate, self.dedt.as_ref());
            col!(SignalSpeed, self.kdk.vsig.as_ref());
            col!(SavedVelocity, save.then_some(&self.kdk.v_save));
            col!(SavedEnergy, self.kdk.e_save.as_ref());
            col!(SmoothingLength, self.sm.gas_h.as_ref());
            col!(Omega, self.sm.gas_omega.as_ref());
            col!(KernelAt, smooth.then_some(&self.sm.kernel_at));
            col!(PressureTerm, smooth.then_some(&self.sm.pt));
            col!(IadMatrix, iad.then_some(&self.sm.iad));
            if let Some(c) = &self.coupling {
                col!(CouplingNorm, Some(&c.s_gas));
                col!(GasIncrement, Some(&c.dv));
                col!(DustIncrement, Some(&c.du), nf);
                col!(CouplingStoppingTime, Some(&c.t_stop), nf);
                col!(CouplingHeat, c.heat.as_ref());
            }
        } else {
            col!(Position, Some(&self.dust.x));
            col!(Velocity, Some(&self.dust.v));
            col!(Mass, Some(&self.dust.m));
            col!(Density, Some(&self.dust.rho));
            col!(KineticLoss, self.dust.loss.as_ref());
            col!(SavedVelocity, save.then_some(&self.kdk.u_save));
            if let Some(c) = &self.coupling {
                col!(CouplingNorm, Some(&c.s_dust));
            }
        }
        out
    }
}

/// `a[i] ← a[perm[i]]` for every i, in place (each cycle of the permutation followed once).
fn permute_in_place<T: Copy>(a: &mut [T], perm: &[u32]) {
    let mut done = vec![false; a.len()];
    for start in 0..a.len() {
        if done[start] {
            continue;
        }
        let first = a[start];
        let mut j = start;
        loop {
            done[j] = true;
            let k = perm[j] as usize;
            if k == start {
                a[j] = first;
                break;
            }
            a[j] = a[k];
            j = k;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::permute_in_place;

    /// The in-place permutation of the ghosts' anchors gives what a copy gives, for
    /// permutations of every cycle structure (identity, one long cycle, scattered).
    #[test]
    fn a_permutation_in_place_matches_the_permuted_copy() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = |n: usize| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % n as u64) as usize
        };
        for n in [0usize, 1, 2, 7, 100, 1000] {
            let a: Vec<[f64; 3]> = (0..n).map(|i| [i as f64, -(i as f64), 0.5]).collect();
            let identity: Vec<u32> = (0..n as u32).collect();
            let rotation: Vec<u32> = (0..n as u32).map(|i| (i + 1) % n as u32).collect();
            let mut shuffled = identity.clone();
            for i in (1..n).rev() {
                shuffled.swap(i, next(i + 1));
            }
            for perm in [identity, rotation, shuffled] {
                let want: Vec<[f64; 3]> = perm.iter().map(|&p| a[p as usize]).collect();
                let mut got = a.clone();
                permute_in_place(&mut got, &perm);
                assert_eq!(got, want, "n = {n}");
            }
        }
    }
}
