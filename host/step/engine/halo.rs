//! Ghost particles over MPI ranks (docs/scaling.md, "A thin halo"): their masks and the
//! refresh of their values from their owners between the step's neighbour passes.
use super::*;

/// Ghost particles: copies of particles another MPI rank owns, within one interaction reach of
/// this rank's own (docs/scaling.md, "A thin halo"). Between the step's neighbour passes the
/// engine hands every particle's per-particle values to [`GhostSync::refresh`], which writes
/// the owners' values into the ghosts' rows; the ghosts keep their density, h and forces out
/// of those passes (their neighbourhoods are cut off at the halo's edge) and out of the step's
/// maxima.
pub trait GhostSync: Send {
    /// Overwrite the ghosts' rows (gas first, then the dust) with their owners' (collective).
    fn refresh(&mut self, tables: &mut [GhostRows<'_>]) -> Result<(), String>;
}

/// One phase's particles as rows of bytes: `keys[i]` = (phase: 0 gas, 1 + k dust fraction k,
/// particle id); row i is `data[i * row .. (i + 1) * row]`, every per-particle buffer's value.
pub struct GhostRows<'a> {
    pub keys: &'a [(u64, u64)],
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
    /// Every slot's key (phase, id), per phase, in the order of the last sort.
    pub(super) slots: [Vec<(u64, u64)>; 2],
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
        self.ghosts = Some(Ghosts {
            sync,
            keys,
            mask: [None, None],
            only: [None, None],
            slots: [Vec::new(), Vec::new()],
        });
        self.ghost_masks()?;
        self.ghost_sync()
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
    pub(super) fn ghost_masks(&mut self) -> Result<(), GpuError> {
        let Some(g) = &self.ghosts else {
            return Ok(());
        };
        let mut masks: [Option<Buf<L, u8>>; 2] = [None, None];
        let mut only: [Option<Buf<L, u8>>; 2] = [None, None];
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
        }
        if let Some(g) = &mut self.ghosts {
            g.mask = masks;
            g.only = only;
            g.slots = slots;
        }
        Ok(())
    }

    /// Refresh the ghosts from their owners (a no-op without ghosts): every per-particle
    /// buffer, as bytes, row by row.
    pub(super) fn ghost_sync(&mut self) -> Result<(), StepError> {
        if self.ghosts.is_none() {
            return Ok(());
        }
        let mut rows = Vec::with_capacity(2);
        for gas in [true, false] {
            let n = if gas { self.gas.n } else { self.dust.n };
            let cols = self.ghost_columns(gas, None)?;
            let row: usize = cols.iter().map(|c| c.len() / n.max(1)).sum();
            let mut data = vec![0u8; n * row];
            let mut at = 0;
            for c in &cols {
                let w = c.len() / n.max(1);
                for i in 0..n {
                    data[i * row + at..i * row + at + w].copy_from_slice(&c[i * w..(i + 1) * w]);
                }
                at += w;
            }
            rows.push((row, data));
        }
        // The slots' keys of the last sort (ghost_masks): no id download per refresh.
        let Ghosts { sync, slots, .. } = self.ghosts.as_mut().expect("checked above");
        let mut tables: Vec<GhostRows<'_>> = (slots.iter().zip(rows))
            .map(|(keys, (row, data))| GhostRows { keys, row, data })
            .collect();
        sync.refresh(&mut tables)
            .map_err(|e| StepError::Blowup(format!("halo exchange: {e}")))?;
        let rows: Vec<(usize, Vec<u8>)> = tables.into_iter().map(|t| (t.row, t.data)).collect();
        for ((row, data), gas) in rows.iter().zip([true, false]) {
            self.ghost_columns(gas, Some((*row, data)))?;
        }
        Ok(())
    }

    /// A phase's per-particle buffers as byte columns (`put` = None), or written back from
    /// the rows of `put`; those this scene's pipeline does not use are left out.
    pub(super) fn ghost_columns(
        &mut self,
        gas: bool,
        put: Option<(usize, &[u8])>,
    ) -> Result<Vec<Vec<u8>>, GpuError> {
        /// Buffer `b` with `per` values per particle, particle-major.
        pub(super) fn one<L: Launcher, T: Copy>(
            d: &Device<L>,
            b: Option<&mut Buf<L, T>>,
            n: usize,
            per: usize,
            put: Option<((usize, &[u8]), &mut usize)>,
            out: &mut Vec<Vec<u8>>,
        ) -> Result<(), GpuError> {
            let Some(b) = b else { return Ok(()) };
            if n == 0 || per == 0 {
                return Ok(());
            }
            let w = std::mem::size_of::<T>() * per;
            match put {
                None => {
                    let mut bytes = vec![0u8; n * w];
                    d.launcher.download(&b.mem, &mut bytes)?;
                    out.push(bytes);
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
            ($b:expr, $n:expr) => {
                one(d, $b, $n, 1, put.map(|t| (t, &mut at)), &mut out)?
            };
            ($b:expr, $n:expr, $per:expr) => {
                one(d, $b, $n, $per, put.map(|t| (t, &mut at)), &mut out)?
            };
        }
        let nf = self.dust.groups;
        if gas {
            let n = self.gas.n;
            col!(Some(&mut self.gas.x), n);
            col!(Some(&mut self.gas.v), n);
            col!(Some(&mut self.gas.m), n);
            col!(Some(&mut self.gas.rho), n);
            col!(self.gas.loss.as_mut(), n);
            col!(Some(&mut self.pres), n);
            col!(Some(&mut self.cs), n);
            col!(self.e.as_mut(), n);
            col!(Some(&mut self.acc), n);
            col!(self.dedt.as_mut(), n);
            col!(self.kdk.vsig.as_mut(), n);
            col!(save.then_some(&mut self.kdk.v_save), n);
            col!(self.kdk.e_save.as_mut(), n);
            col!(self.sm.gas_h.as_mut(), n);
            col!(self.sm.gas_omega.as_mut(), n);
            col!(smooth.then_some(&mut self.sm.kernel_at), n);
            col!(smooth.then_some(&mut self.sm.pt), n);
            col!(iad.then_some(&mut self.sm.iad), n);
            if let Some(c) = &mut self.coupling {
                col!(Some(&mut c.s_gas), n);
                col!(Some(&mut c.dv), n);
                col!(Some(&mut c.du), n, nf);
                col!(Some(&mut c.t_stop), n, nf);
                col!(c.heat.as_mut(), n);
            }
        } else {
            let n = self.dust.n;
            col!(Some(&mut self.dust.x), n);
            col!(Some(&mut self.dust.v), n);
            col!(Some(&mut self.dust.m), n);
            col!(Some(&mut self.dust.rho), n);
            col!(self.dust.loss.as_mut(), n);
            col!(save.then_some(&mut self.kdk.u_save), n);
            if let Some(c) = &mut self.coupling {
                col!(Some(&mut c.s_dust), n);
            }
        }
        Ok(out)
    }
}
