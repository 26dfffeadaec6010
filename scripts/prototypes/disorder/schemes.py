"""Drag schemes: each takes (sim, vt, ut) and returns (v_new, [u_new_k], diag)."""
import numpy as np
from sim import kmat, cell_solve


def geom(sim):
    Rg = kmat(sim.xg, sim.xg, sim.h, key="gg")
    Rk = [kmat(x, sim.xg, sim.h, key=("dg", k)) for k, x in enumerate(sim.xd)]
    return Rg, Rk


def deposits(sim, Rg, Rk, vt, ut):
    Mg = Rg.T @ np.full(Rg.shape[0], sim.mg)
    Vt = (Rg.T @ (sim.mg * vt)) / Mg[:, None]
    Mk = [R.T @ np.full(R.shape[0], m) for R, m in zip(Rk, sim.md)]
    Uk = [(R.T @ (m * u)) / np.maximum(M, 1e-300)[:, None] for R, m, u, M in zip(Rk, sim.md, ut, Mk)]
    return Mg, Vt, Mk, Uk


def kernel(sim, vt, ut):
    """current dustsph scheme (method.md §K)"""
    Rg, Rk = geom(sim)
    Mg, Vt, Mk, Uk = deposits(sim, Rg, Rk, vt, ut)
    eps = [M / Mg for M in Mk]
    beta = [np.where(M > 0, sim.tau / t, 0.0) for M, t in zip(Mk, sim.ts)]
    Vn, Un = cell_solve(Vt, Uk, eps, beta)
    v = vt + Rg @ (Vn - Vt)
    u = [uu + R @ (U1 - U0) for uu, R, U1, U0 in zip(ut, Rk, Un, Uk)]
    return v, u, dict(eps=eps, Mg=Mg, Mk=Mk, Vn=Vn, Un=Un)


def kernel_epsglobal(sim, vt, ut):
    """DIAGNOSTIC (not momentum-exact): the solve with the global eps in every cell"""
    Rg, Rk = geom(sim)
    Mg, Vt, Mk, Uk = deposits(sim, Rg, Rk, vt, ut)
    eps = [np.full_like(Mg, e) for e in sim.eps0]
    beta = [np.where(M > 0, sim.tau / t, 0.0) for M, t in zip(Mk, sim.ts)]
    Vn, Un = cell_solve(Vt, Uk, eps, beta)
    v = vt + Rg @ (Vn - Vt)
    u = [uu + R @ (U1 - U0) for uu, R, U1, U0 in zip(ut, Rk, Un, Uk)]
    return v, u, {}


def richardson(R, m, M, dV, K):
    """z with D R z ~= dV (D = diag(1/M) R^T diag(m)); z0 = dV; sum M z == sum M dV at every iterate"""
    z = dV.copy()
    for _ in range(K):
        z = z + (dV - (R.T @ (m * (R @ z))) / np.maximum(M, 1e-300)[:, None])
    return z


def make_consistent(K, phases="gd"):
    def sch(sim, vt, ut):
        Rg, Rk = geom(sim)
        Mg, Vt, Mk, Uk = deposits(sim, Rg, Rk, vt, ut)
        eps = [M / Mg for M in Mk]
        beta = [np.where(M > 0, sim.tau / t, 0.0) for M, t in zip(Mk, sim.ts)]
        Vn, Un = cell_solve(Vt, Uk, eps, beta)
        zg = richardson(Rg, sim.mg, Mg, Vn - Vt, K if "g" in phases else 0)
        v = vt + Rg @ zg
        u = [uu + R @ richardson(R, m, M, U1 - U0, K if "d" in phases else 0)
             for uu, R, U1, U0, m, M in zip(ut, Rk, Un, Uk, sim.md, Mk)]
        return v, u, {}
    return sch


def eps_hat(sim, Rg, Mg, Mk, kind):
    if kind == "global":
        return [np.full_like(Mg, e) for e in sim.eps0]
    # smoothing of the mass fields over the gas cells with the gas weights (one extra walk per pass)
    out = []
    for M in Mk:
        A, B = M, Mg
        for _ in range(int(kind[-1])):
            A, B = Rg @ A, Rg @ B
        out.append(A / B)
    return out


def make_split(kind, who="dust"):
    """solve with eps_hat; 'dust': dust takes the eps_hat increments, gas pays J/M_g per cell;
    'gas': gas takes the eps_hat increment, each fraction pays its share (eps_hat_k weighting)"""
    def sch(sim, vt, ut):
        Rg, Rk = geom(sim)
        Mg, Vt, Mk, Uk = deposits(sim, Rg, Rk, vt, ut)
        eh = eps_hat(sim, Rg, Mg, Mk, kind)
        beta = [np.where(M > 0, sim.tau / t, 0.0) for M, t in zip(Mk, sim.ts)]
        Vn, Un = cell_solve(Vt, Uk, eh, beta)
        if who == "dust":
            dU = [U1 - U0 for U1, U0 in zip(Un, Uk)]
            dV = -sum((M / Mg)[:, None] * d for M, d in zip(Mk, dU))
        else:
            dV = Vn - Vt
            # per-fraction momentum of the eps_hat solve, rescaled so that sum_k J_k = -M_g dV exactly
            Jh = [e[:, None] * (U1 - U0) for e, U1, U0 in zip(eh, Un, Uk)]  # per unit gas mass
            dU = [(Mg / np.maximum(M, 1e-300))[:, None] * j for M, j in zip(Mk, Jh)]
        v = vt + Rg @ dV
        u = [uu + R @ d for uu, R, d in zip(ut, Rk, dU)]
        return v, u, {}
    return sch
