#!/usr/bin/env python3
"""IDIC cell drag across individual (block, power-of-two) time bins: a NumPy model.

Run: python3 docs/decisions/drag-across-bins.py        (NumPy only, single thread, < 1 min)

1D periodic, monodisperse cell IDIC (method.md §3.3 with N = 1: cell means of the predicted
velocities, closed-form implicit solve over the cell's interval; particle update below),
first-order step (§3.6: forces at the start of a particle's step, kick + drag, drift with
the new velocity). Stopping time t = t_k of method.md §1.1 (gas drag (eps/t)(u - v), dust
-(u - v)/t). Bin k has step dt/2^k; a substep is one step of the finest bin; a particle is
"active" at the end of a substep when its bin's step ends there. Schemes:
  G    global step (every particle in one bin; G0 = base dt, Gk = finest bin).
  A    every cell with >= 1 active member solves, over the step of its finest active member,
       for ALL members; each member's predicted velocity is v + (t - t_kick) A with A its
       non-drag acceleration from the start of its own step (the slow member's kick is spread
       over the substeps); forces only at a particle's own step start.
  A1   as A, but every particle takes its whole kick (own step x A) at its own step start;
       the solves then carry no force (all schemes below kick this way too).
  B    a phase of a cell takes part only when one of its members is active; an inactive phase
       is a frozen partner: the active phase is solved implicitly against its current mean,
       and the opposite momentum goes to a per-particle ledger applied when the partner next
       takes part; both phases active: the joint solve.
  B2   drag only when both phases are active (the slow member's step), over the slow step;
       between, force-only kicks.
  C    at each base step every particle takes the finest bin in its cell (cells synchronised),
       then as A1.
Measures: (1) the dusty box (method.md §7.1) against exp(-(1+eps)t/t_k), momentum drift;
(2) the stiff terminal drift under a constant force on one phase, w = t (a_d - a_g)/(1+eps);
(3) the dusty wave (method.md §7.2, isothermal, SPH cubic spline, fixed h) against the exact
linear solution and a global run at a step 8x finer than the finest bin; counts of gas force
evaluations and of particle drag updates; (4) the wave to t = 10 against the finest global step.
Particle update: the predicted velocity plus the change of its cell's mean; --relax uses the
method.md §3.3 form (each particle relaxes to the partner's new mean). Results and the decision:
docs/decisions/drag-across-bins.md.
"""
import sys
import time
import numpy as np

RELAX = "--relax" in sys.argv

T0 = time.time()


class Prob:
    """Particles (x, v, m, is-dust), t_k, external a_g/a_d, ncell cells on [0, L), optional SPH."""
    def __init__(s, x, v, m, dust, tk, ncell, ag=0.0, ad=0.0, h=None, cs=1.0, drift=False):
        s.x, s.v, s.m, s.dust, s.tk, s.nc = x, v, m, dust, tk, ncell
        s.ag, s.ad, s.h, s.cs, s.drift, s.L = ag, ad, h, cs, drift, 1.0
        s.rho_scale = 1.0

    def cell(s, x):
        return np.minimum((x / s.L * s.nc).astype(int), s.nc - 1)

    def gas_rho_acc(s, x):
        """SPH density and pressure acceleration of the gas (isothermal p = cs^2 rho)."""
        g = ~s.dust
        xg, mg, h = x[g], s.m[g], s.h                  # gas keeps its 1D order: neighbours
        off = np.arange(-3, 4)                          # are the index offsets -3..3
        nb = (np.arange(len(xg))[:, None] + off[None, :]) % len(xg)
        r = xg[:, None] - xg[nb]
        r -= s.L * np.round(r / s.L)
        q = np.abs(r) / h
        f = np.where(q < 1, 1 - 1.5 * q**2 + 0.75 * q**3, np.where(q < 2, 0.25 * (2 - q)**3, 0))
        fp = np.where(q < 1, -3 * q + 2.25 * q**2, np.where(q < 2, -0.75 * (2 - q)**2, 0))
        rho = (mg[nb] * f).sum(1) * 2 / (3 * h) * s.rho_scale
        dW = 2 / (3 * h * h) * fp * np.sign(r)
        pr = s.cs**2 * rho / rho**2
        acc = -(mg[nb] * (pr[:, None] + pr[nb]) * dW).sum(1)
        return rho, acc

    def accel(s, x):
        a = np.where(s.dust, s.ad, s.ag).astype(float)
        if s.h is not None:
            a[~s.dust] += s.gas_rho_acc(x)[1]
        return a


def run(P, scheme, bins, dt, t_end):
    """Integrate; returns final (x, v) and per-substep history rows
    (t, P_vel, P_vel+ledger, <v_gas>, <u_dust>, is_base_sync) and counts."""
    x, v, m, dust, gas, nc = P.x.copy(), P.v.copy(), P.m, P.dust, ~P.dust, P.nc
    n = len(x)
    kmax = int(bins.max())
    nsub = 2**kmax
    d = dt / nsub
    A, tkick, led = np.zeros(n), np.zeros(n), np.zeros(n)
    b = bins.copy()
    nforce = ndrag = 0
    hist = []
    Mg_all, Md_all = m[gas].sum(), m[dust].sum()
    for nb in range(int(round(t_end / dt))):
        if scheme == "C":                      # synchronise every cell to its finest member
            cb = np.zeros(nc, int)
            np.maximum.at(cb, P.cell(x), bins)
            b = cb[P.cell(x)]
        stride = 2**(kmax - b)
        slen = stride * d
        for s in range(nsub):
            te = (nb * nsub + s + 1) * d
            start = s % stride == 0
            if start.any():                    # non-drag forces at the start of own step
                A[start] = P.accel(x)[start]
                nforce += int((start & gas).sum())
                if scheme != "A":              # whole kick now; the solves carry no force
                    v[start] += slen[start] * A[start]
                    tkick[start] = (nb * nsub + s) * d + slen[start]
            act = (s + 1) % stride == 0
            c = P.cell(x)
            cs = lambda w: np.bincount(c, w, minlength=nc)
            if scheme in ("A", "A1", "C", "G"):
                part = (cs(act.astype(float)) > 0)[c]
                gfro = dfro = np.zeros(nc, bool)
                Lc = np.full(nc, np.inf)
                np.minimum.at(Lc, c[act], slen[act])
            else:
                gact = cs((act & gas).astype(float)) > 0
                dact = cs((act & dust).astype(float)) > 0
                part = np.where(dust, dact[c], gact[c])
                gfro, dfro = ~gact, ~dact
                Lc = np.full(nc, np.inf)
                if scheme == "B":
                    np.minimum.at(Lc, c[act], slen[act])
                else:                          # B2: drag over the slow step, only when synced
                    Lc = np.zeros(nc)
                    np.maximum.at(Lc, c, slen)
                    Lc[gfro | dfro] = np.inf
            vt = v.copy()
            kick = np.maximum(te - tkick, 0.0)  # A1: zero until the next step start
            vt[part] += kick[part] * A[part] + led[part]
            led[part] = 0.0
            tkick[part] = np.maximum(tkick[part], te)
            ndrag += int(part.sum())
            Mg, Md = cs(m * gas), cs(m * dust)
            ok = (Mg > 0) & (Md > 0) & np.isfinite(Lc)
            Vt = np.divide(cs(m * vt * gas), Mg, out=np.zeros(nc), where=Mg > 0)
            Ut = np.divide(cs(m * vt * dust), Md, out=np.zeros(nc), where=Md > 0)
            eps = np.where(ok, Md / np.where(Mg > 0, Mg, 1), 0.0)
            beta = np.where(ok, np.where(np.isfinite(Lc), Lc, 0) / P.tk, 0.0)
            eb = eps * beta
            Vj = (Vt + eb * Ut / (1 + beta)) / (1 + eb / (1 + beta))
            Vn = np.where(gfro, Vt, np.where(dfro, (Vt + eb * Ut) / (1 + eb), Vj))
            Un = np.where(dfro, Ut, (Ut + beta * Vn) / (1 + beta))
            pg, pd = part & gas, part & dust
            cg, cd = c[pg], c[pd]
            if RELAX:                          # method.md §3.3: relax to the partner's mean
                v[pg] = (vt[pg] + eb[cg] * Un[cg]) / (1 + eb[cg])
                v[pd] = (vt[pd] + beta[cd] * Vn[cd]) / (1 + beta[cd])
            else:                              # the brief's form: + change of the cell mean
                v[pg] = vt[pg] + (Vn - Vt)[cg]
                v[pd] = vt[pd] + (Un - Ut)[cd]
            if scheme == "B":                  # ledger: the frozen phase's share of the exchange
                lg = np.where(gfro & ~dfro, -eps * (Un - Ut), 0.0)
                ld = np.where(dfro & ~gfro & (eps > 0),
                              -(Vn - Vt) / np.where(eps > 0, eps, 1), 0.0)
                led[gas] += lg[c[gas]]
                led[dust] += ld[c[dust]]
            if P.drift:
                x = (x + d * v) % P.L
            hist.append((te, (m * v).sum(), (m * (v + led)).sum(),
                         (m * v)[gas].sum() / Mg_all, (m * v)[dust].sum() / Md_all,
                         s == nsub - 1))
    return x, v, np.array(hist), nforce, ndrag


def box(tk, ag=0.0, ad=0.0, v0=0.0, u0=1.0, ncell=4, ppc=2):
    """Uniform box, rho_g = rho_d = 1 (eps = 1), ppc particles per phase per cell, no drift."""
    ng = ncell * ppc
    x = np.tile((np.arange(ng) + 0.5) / ng, 2)
    dust = np.repeat([False, True], ng)
    return Prob(x, np.where(dust, u0, v0), np.full(2 * ng, 1.0 / ng), dust, tk, ncell, ag, ad)


SCHEMES = ["A", "A1", "B", "B2", "C"]


def bins_for(P, cfg, kf):
    """Bins by hand: 'gas0' = gas 0 / dust kf, 'dust0' = dust 0 / gas kf,
    'alt' = even cells gas 0 / dust kf, odd cells reversed."""
    if cfg == "gas0":
        return np.where(P.dust, kf, 0)
    if cfg == "dust0":
        return np.where(P.dust, 0, kf)
    even = P.cell(P.x) % 2 == 0
    return np.where(even ^ P.dust, 0, kf)


def fmt(a):
    return " ".join(f"{z:9.1e}" for z in a)


# ---------------------------------------------------------------- 1. dusty box
DT, KF = 0.1, 3
ratios = [1e-6, 1e-3, 0.1, 1.0, 10.0]
print(f"1. DUSTY BOX  eps = 1, v0 = 0, u0 = 1, dt = {DT}, t = 1, fine bin {KF};"
      " max|v - v_exact| over all particles (units of w0 = 1)")
print(f"{'scheme':14s} " + " ".join(f"t/dt={r:<5.0e}" for r in ratios)
      + "   |dP| all substeps   |dP| at sync")
rows = [("G0", "gas0", 0), (f"G{KF}", "gas0", KF)] + \
       [(sc, cfg, KF) for cfg in ("gas0", "dust0") for sc in SCHEMES]
for sc, cfg, kf in rows:
    errs, dp_all, dp_sync = [], 0.0, 0.0      # initial momentum: dust mass 1 at u0 = 1
    for r in ratios:
        P = box(r * DT)
        bins = np.full(len(P.x), kf) if sc[0] == "G" else bins_for(P, cfg, kf)
        x, v, H, _, _ = run(P, "G" if sc[0] == "G" else sc, bins, DT, 1.0)
        w = np.exp(-2 * 1.0 / P.tk)
        vex = np.where(P.dust, 0.5 + 0.5 * w, 0.5 - 0.5 * w)
        errs.append(np.abs(v - vex).max())
        dp_all = max(dp_all, np.abs(H[:, 1] - 1.0).max())
        dp_sync = max(dp_sync, np.abs(H[H[:, 5] > 0, 1] - 1.0).max())
    name = sc if sc[0] == "G" else f"{sc} {cfg}"
    print(f"{name:14s} {fmt(errs)}      {dp_all:9.1e}         {dp_sync:9.1e}")

# ------------------------------------------------- 2. stiff terminal drift
print(f"\n2. STIFF TERMINAL DRIFT  t_k/dt = 1e-6, eps = 1, from rest, dt = {DT}, t = 10 "
      "(100 base steps).\n   exact terminal w = u - v = t_k (a_d - a_g)/(1 + eps); w/w_term at the "
      "last sync, min/max/mean over the substeps of the last base step;\n   growth = max|w| last "
      "base step / max|w| 2nd base step; V = total momentum / total mass at the last sync;\n"
      "   both=-1: exact w = 0, columns in units of t_k |g|/(1 + eps)")
print(f"{'force':8s}{'scheme':11s}{'@sync':>9s}{'min':>10s}{'max':>10s}{'mean':>11s}"
      f"{'growth':>8s}{'|V-Vex|/Vex':>13s}")
for lab, ag, ad in (("a_d=-1", 0.0, -1.0), ("a_g=-1", -1.0, 0.0), ("both=-1", -1.0, -1.0)):
    for sc, cfg, kf in rows:
        P = box(1e-6 * DT, ag=ag, ad=ad, u0=0.0)
        bins = np.full(len(P.x), kf) if sc[0] == "G" else bins_for(P, cfg, kf)
        x, v, H, _, _ = run(P, "G" if sc[0] == "G" else sc, bins, DT, 10.0)
        wterm = P.tk * (ad - ag) / 2 or P.tk / 2     # equal forces: w = 0, units t_k g/(1+eps)
        r = ((H[:, 4] - H[:, 3]) / wterm)[-2**kf:]   # substeps of the last base step
        with np.errstate(all="ignore"):
            growth = np.abs(H[-2**kf:, 4] - H[-2**kf:, 3]).max() / \
                np.abs(H[2**kf:2**(kf + 1), 4] - H[2**kf:2**(kf + 1), 3]).max()
        Vex = (ag + ad) / 2 * 10.0
        name = sc if sc[0] == "G" else f"{sc} {cfg}"
        print(f"{lab:8s}{name:11s}{r[-1]:9.4f}{r.min():10.3g}{r.max():10.3g}{r.mean():11.3g}"
              f"{growth:8.3f}{abs(H[-1, 1] / 2 - Vex) / abs(Vex):13.1e}")

# ------------------------------------------------------------- 3. dusty wave
NW, AMP, KW = 100, 1e-4, 2 * np.pi


def wave(tk):
    """Sine mode (method.md §7.2): rho_g = rho_d = 1, cs = 1, k = 2 pi, gas and dust on the
    same mass-coordinate lattice, h = 1.2 dx, cells of 2 dx (2 particles per phase)."""
    xi = (np.arange(NW) + 0.5) / NW
    x = xi.copy()
    for _ in range(20):                        # x + (A/k)(1 - cos kx) = xi
        x -= (x + AMP / KW * (1 - np.cos(KW * x)) - xi) / (1 + AMP * np.sin(KW * x))
    x = np.tile(x, 2)
    dust = np.repeat([False, True], NW)
    P = Prob(x, AMP * np.sin(KW * x), np.full(2 * NW, 1.0 / NW), dust, tk, NW // 2,
             h=1.2 / NW, drift=True)
    P0 = Prob(np.tile(xi, 2), 0 * x, P.m, dust, tk, NW // 2, h=1.2 / NW)
    P.rho_scale = 1.0 / P0.gas_rho_acc(P0.x)[0].mean()   # SPH lattice density -> 1
    return P


def wave_exact(tk, t, x):
    """Exact linear two-fluid solution (method.md §7.2): (rho_g, v, rho_d, u) at x."""
    e = 1.0
    M = np.array([[0, -1j * KW, 0, 0], [-1j * KW, -e / tk, 0, e / tk],
                  [0, 0, 0, -1j * KW], [0, 1 / tk, 0, -1 / tk]], complex)
    lam, R = np.linalg.eig(M)
    y = R @ (np.exp(lam * t) * np.linalg.solve(R, -1j * np.ones(4)))
    return [1 + AMP * (y[0] * np.exp(1j * KW * x)).real, AMP * (y[1] * np.exp(1j * KW * x)).real]


DTW, KW2, TW = 0.004, 2, 1.0
TKW = (1e6, 1e-2, 1e-4)
print(f"\n3. DUSTY WAVE  N = {NW}/phase, h = 1.2dx, cells 2dx, A = {AMP}, base dt = {DTW} "
      f"(c dt/h = {DTW * NW / 1.2:.2f}), fine bin {KW2}, t = {TW}.\n   L1 errors in units of A; "
      f"'ref' = global run at dt/{2**KW2 * 8}; nF = gas force evals, nD = particle drag updates")
print(f"{'t_k':7s}{'scheme':14s}{'rho_g ex':>10s}{'v_g ex':>10s}{'v_g ref':>10s}{'u_d ref':>10s}"
      f"{'|dP|/(M A)':>11s}{'nF':>8s}{'nD':>8s}")
for tk in TKW:
    P = wave(tk)
    g = ~P.dust
    nref = 2**KW2 * 8
    xr, vr, _, _, _ = run(P, "G", np.zeros(2 * NW, int), DTW / nref, TW)
    wrows = [("G0", "gas0", 0), (f"G{KW2}", "gas0", KW2)] + \
            [(sc, cfg, KW2) for cfg in ("gas0", "dust0", "alt") for sc in SCHEMES]
    for sc, cfg, kf in wrows:
        bins = np.full(2 * NW, kf) if sc[0] == "G" else bins_for(P, cfg, kf)
        x, v, H, nF, nD = run(P, "G" if sc[0] == "G" else sc, bins, DTW, TW)
        rho = P.gas_rho_acc(x)[0]
        rex, vex = wave_exact(tk, TW, x[g])
        l1 = lambda a, b: np.abs(a - b).mean() / AMP
        dP = np.abs(H[:, 1] - (P.m * P.v).sum()).max() / (2 * AMP)
        name = sc if sc[0] == "G" else f"{sc} {cfg}"
        print(f"{tk:<7.0e}{name:14s}{l1(rho, rex):10.2e}{l1(v[g], vex):10.2e}"
              f"{l1(v[g], vr[g]):10.2e}{l1(v[~g], vr[~g]):10.2e}{dP:11.1e}{nF:8d}{nD:8d}")
TL = 10.0
print(f"\n4. LONG WAVE RUN  t_k = 1e-2, t = {TL} (2500 base steps): max|v_g|/A at the end "
      f"and L1 v_g against G{KW2} (units of A)")
P = wave(1e-2)
ref = None
for sc, cfg, kf in [(f"G{KW2}", "gas0", KW2), ("G0", "gas0", 0)] + \
        [(sc, cfg, KW2) for cfg in ("gas0", "alt") for sc in SCHEMES]:
    bins = np.full(2 * NW, kf) if sc[0] == "G" else bins_for(P, cfg, kf)
    with np.errstate(all="ignore"):
        x, v, H, nF, nD = run(P, "G" if sc[0] == "G" else sc, bins, DTW, TL)
    ref = v[:NW] if ref is None else ref
    name = sc if sc[0] == "G" else f"{sc} {cfg}"
    print(f"   {name:10s} max|v_g|/A = {np.abs(v[:NW]).max() / AMP:9.3g}   "
          f"L1 vs G{KW2} = {np.abs(v[:NW] - ref).mean() / AMP:9.3g}")
print(f"\nrun time {time.time() - T0:.1f} s")
