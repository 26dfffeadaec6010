"""Damping the dust's unresolved velocity dispersion in the kernel coupling (method.md §K), in the
NumPy model of the drag step alone (scripts/prototypes/drag_coupling.py: 3D periodic box, n = 16
per phase, hfact 1.2, dust offset half a spacing). Forms of the dust particles' update after the
kernel coupling's return of increments (FLIP):
  flip     as built: u_j <- u~_j + sum_a w_ja (U_a^new - U~_a)
  pic      then u_j <- u_j - f (u_j - T_j), T_j = sum_a w_ja U_a^new (relax toward the smoothed field)
  pic+gas  the same toward T_j = sum_a w_ja (U_a^new + d_a), d_a = v_a^new - sum_c w_ac V_c^new the
           gas particle's own deviation from its smoothed field (equal to the dust's for a smooth
           co-moving field, so that only the unresolved part is damped)
with f = 1 - exp(-tau/t_s), and the momentum the damping takes from the dust handed to the gas
with the same weights (exact). Cases: a co-moving sine (its amplitude must stay), dust velocity
noise on gas at rest (it should decay at the drag rate), the terminal drift under a force.
    python3 scripts/prototypes/dispersion_damping.py"""
import sys, os
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drag_coupling import lattice, kernel_solve

def step(form, xg, vg, xd, ud, mg, md, tau, ts, ag, h):
    vt, wg, wd, Vg, Ud, Vn, Un, _ = kernel_solve(xg, vg, xd, ud, mg, md, tau, ts, ag, h)
    vn = vt + wg @ (Vn - Vg); un = ud + wd @ (Un - Ud)
    if form == "flip":
        return vn, un
    f = 1 - np.exp(-tau / ts)
    target = Un if form == "pic" else Un + (vn - wg @ Vn)
    dev = un - wd @ target
    un2 = un - f * dev
    # the momentum the dust lost, to the gas with the dust particles' weights
    vn2 = vn + (wd.T @ (md * f * dev)) / mg
    return vn2, un2

def run(form, mode, n=16, shift=0.5, hfact=1.2, ts=1e-6, tau=1e-3, steps=100, eps0=1.0, a=10.0, seed=1):
    rng = np.random.default_rng(seed)
    xg = lattice(n, 0.0) % 1; xd = lattice(n, shift) % 1
    mg = 1.0 / n ** 3; md = eps0 / n ** 3; h = hfact / n
    N = len(xg)
    vg = np.zeros((N, 3)); ud = np.zeros((N, 3)); ag = np.zeros((N, 3))
    A = 1e-3
    if mode == "drift":
        ag[:, 0] = a
    elif mode == "wave":
        vg[:, 0] = A * np.sin(2 * np.pi * xg[:, 0]); ud[:, 0] = A * np.sin(2 * np.pi * xd[:, 0])
    elif mode == "noise":
        ud = A * rng.normal(size=(N, 3)); ud -= ud.mean(0)
    p0 = mg * vg.sum(0) + md * ud.sum(0)
    for s in range(steps):
        vg, ud = step(form, xg, vg, xd, ud, mg, md, tau, ts, ag, h)
        xg = (xg + tau * vg) % 1.0; xd = (xd + tau * ud) % 1.0
    out = {"mom": np.abs(mg * vg.sum(0) + md * ud.sum(0) - tau * steps * mg * ag.sum(0) - p0).max()}
    if mode == "drift":
        de = ts * a / (1 + eps0)
        out["drift_err"] = (vg[:, 0].mean() - ud[:, 0].mean()) / de - 1
        out["scat_d"] = ud[:, 0].std() / de
    elif mode == "wave":
        out["amp_g"] = -1 + 2 * (vg[:, 0] * np.sin(2 * np.pi * xg[:, 0])).mean() / A
        out["amp_d"] = -1 + 2 * (ud[:, 0] * np.sin(2 * np.pi * xd[:, 0])).mean() / A
    elif mode == "noise":
        out["dust_rms"] = ud.std() / A; out["gas_rms"] = vg.std() / A
    return out

if __name__ == "__main__":
    for mode, ts, steps in [("wave", 1e-6, 200), ("noise", 1e-2, 20), ("noise", 1e-6, 5), ("drift", 1e-4, 100)]:
        for form in ["flip", "pic", "pic+gas"]:
            r = run(form, mode, ts=ts, steps=steps)
            print(mode, ts, steps, form, {k: f"{v:.3g}" for k, v in r.items()}, flush=True)
