//! The scatter form: the deposits summed atomically on each gas particle, then the solve.
use super::*;

/// Slots of one phase's deposit on one gas particle in the scatter form's sums: Σ w m,
/// Σ w m ṽ (3), Σ w m ρ, Σ w m sqrt(p/ρ).
pub const DEPOSIT_SLOTS: usize = 6;

/// Atomic f64 add (compare-and-swap on the bits: the same code on the GPU and on the CPU's cores).
/// The scatter sums stay f64 in every precision: their order is the hardware's anyway.
#[inline(always)]
unsafe fn atomic_add_f64(p: *mut f64, v: f64) {
    let a = AtomicU64::from_ptr(p as *mut u64);
    let mut old = a.load(Ordering::Relaxed);
    loop {
        let new = (f64::from_bits(old) + v).to_bits();
        match a.compare_exchange_weak(old, new, Ordering::Relaxed, Ordering::Relaxed) {
            Ok(_) => return,
            Err(x) => old = x,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ScatterDepositArgs<R> {
    pub couple: CoupleArgs<R>,
    /// The depositing phase (the gas, or the dust), and 1 when it is the gas.
    pub ph: PhaseBufs<R>,
    pub is_gas: u32,
    /// Per gas particle a, phase slot s (0 gas, 1 + k fraction k): DEPOSIT_SLOTS sums at
    /// (a·(1 + nf) + s)·DEPOSIT_SLOTS; zeroed before the launch. f64 in every precision.
    pub sums: *mut f64,
}

/// Scatter form of the deposits (the design card's atomicAdd): particle t adds its share to
/// each gas particle of its return row. The sums' order is the hardware's: not bit-reproducible.
pub unsafe fn coupling_scatter<R: Real>(t: usize, a: &ScatterDepositArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() || kernels::is_fixed(ph.fixed(), t) {
        return;
    }
    let c = &a.couple;
    let p = &c.p;
    let gas = a.is_gas != 0;
    let s = if gas {
        *c.cb.s_gas.add(t)
    } else {
        *c.cb.s_dust.add(t)
    };
    if s <= R::ZERO {
        return;
    }
    let (vel, cs, slot) = if gas {
        (gas_base_velocity(c, t), gas_sound(c, t), 0)
    } else {
        (*ph.v.add(t), R::ZERO, 1 + ph.group_of(t))
    };
    let (m, rho) = (*ph.m.add(t), *ph.rho.add(t));
    let stride = 1 + p.nf as usize;
    let row = if gas { t } else { c.gas.len() + t };
    let (idx, ws) = c.cb.pairs.ret(row);
    for (&g, &w) in idx.iter().zip(ws) {
        let wm = w / s * m;
        let o = a.sums.add((g as usize * stride + slot) * DEPOSIT_SLOTS);
        atomic_add_f64(o, wm.to_f64());
        for (d, v) in vel.iter().enumerate() {
            atomic_add_f64(o.add(1 + d), (wm * *v).to_f64());
        }
        atomic_add_f64(o.add(4), (wm * rho).to_f64());
        atomic_add_f64(o.add(5), (wm * cs).to_f64());
    }
}

/// The solve of gas particle t from the scatter form's sums.
pub unsafe fn coupling_solve_sums<R: Real>(t: usize, a: &ScatterDepositArgs<R>) {
    let c = &a.couple;
    if t >= c.gas.len() {
        return;
    }
    let nf = c.p.nf as usize;
    let stride = 1 + nf;
    let dep = |slot: usize| {
        let o = a.sums.add((t * stride + slot) * DEPOSIT_SLOTS);
        kernels::Deposit {
            mass: R::from_f64(*o),
            mom: [
                R::from_f64(*o.add(1)),
                R::from_f64(*o.add(2)),
                R::from_f64(*o.add(3)),
            ],
            rho: R::from_f64(*o.add(4)),
            cs: R::from_f64(*o.add(5)),
        }
    };
    let mut dust_dep = [kernels::Deposit::default(); MAX_FRACTIONS];
    for (f, d) in dust_dep.iter_mut().enumerate().take(nf) {
        *d = dep(1 + f);
    }
    coupling_finish(t, c, &dep(0), &dust_dep);
}
