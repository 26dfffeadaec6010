"""Prototype of the drag step alone (no pressure): gas + one dust fraction, 3D periodic unit box.
Schemes: ngp (today's IDIC), pic, flip, flipd (flip + per-particle relative damping)."""
import numpy as np, sys

def lattice(n, shift):
    g = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    x = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
    return (x + shift / n) % 1.0

def weights(x, nc, order):
    """cell indices (N, S) flat and weights (N, S); tensor B-spline of given order (0 ngp, 1 cic, 2 tsc)"""
    s = x * nc
    if order == 0:
        i = np.floor(s).astype(int) % nc
        idx = i[:, 0] * nc * nc + i[:, 1] * nc + i[:, 2]
        return idx[:, None], np.ones((len(x), 1))
    per_axis = []
    for d in range(3):
        sd = s[:, d]
        if order == 1:
            i0 = np.floor(sd - 0.5).astype(int)
            f = sd - 0.5 - i0
            ids = [i0, i0 + 1]
            ws = [1 - f, f]
        else:
            ic = np.floor(sd).astype(int)
            f = sd - ic - 0.5  # in [-0.5,0.5)
            ids = [ic - 1, ic, ic + 1]
            ws = [0.5 * (0.5 - f) ** 2, 0.75 - f * f, 0.5 * (0.5 + f) ** 2]
        per_axis.append(([j % nc for j in ids], ws))
    idx, w = [], []
    for a in range(len(per_axis[0][0])):
        for b in range(len(per_axis[1][0])):
            for c in range(len(per_axis[2][0])):
                idx.append(per_axis[0][0][a] * nc * nc + per_axis[1][0][b] * nc + per_axis[2][0][c])
                w.append(per_axis[0][1][a] * per_axis[1][1][b] * per_axis[2][1][c])
    return np.stack(idx, 1), np.stack(w, 1)

def deposit(idx, w, q, ncell):
    out = np.zeros((ncell,) + q.shape[1:])
    for s in range(idx.shape[1]):
        np.add.at(out, idx[:, s], (w[:, s] * q.T).T if q.ndim > 1 else w[:, s] * q)
    return out

def interp(idx, w, f):
    return sum((w[:, s] * f[idx[:, s]].T).T for s in range(idx.shape[1]))

def step(scheme, xg, vg, xd, ud, mg, md, tau, ts, ag, nc, order):
    ncell = nc ** 3
    vt = vg + tau * ag
    ig, wg = weights(xg, nc, order)
    idd, wd = weights(xd, nc, order)
    Mg = deposit(ig, wg, np.full(len(xg), mg), ncell)
    Md = deposit(idd, wd, np.full(len(xd), md), ncell)
    Pg = deposit(ig, wg, mg * vt, ncell)
    Pd = deposit(idd, wd, md * ud, ncell)
    ok = (Mg > 0) & (Md > 0)
    eps = np.where(ok, Md / np.maximum(Mg, 1e-300), 0.0)
    Vg = np.where(Mg[:, None] > 0, Pg / np.maximum(Mg, 1e-300)[:, None], 0)
    Ud = np.where(Md[:, None] > 0, Pd / np.maximum(Md, 1e-300)[:, None], 0)
    beta = np.where(ok, tau / ts, 0.0)
    wfac = eps * beta / (1 + beta)
    Vn = (Vg + wfac[:, None] * Ud) / (1 + wfac)[:, None]
    Un = (Ud + beta[:, None] * Vn) / (1 + beta)[:, None]
    if scheme == "ngp" or scheme == "pic":
        # particle relaxes toward the other phase's (interpolated) new cell velocity, own-cell eps/beta
        eb = interp(ig, wg, eps * beta)
        un_g = interp(ig, wg, Un * (eps * beta)[:, None])
        vg_new = (vt + un_g) / (1 + eb)[:, None]
        bd = interp(idd, wd, beta)
        vn_d = interp(idd, wd, Vn * beta[:, None])
        ud_new = (ud + vn_d) / (1 + bd)[:, None]
        return vg_new, ud_new
    # flip: increments
    vg_new = vt + interp(ig, wg, Vn - Vg)
    ud_new = ud + interp(idd, wd, Un - Ud)
    return vg_new, ud_new

def run(scheme, n=16, shift=0.5, hfact=1.2, cfac=1.0, order=2, ts=1e-6, tau=1e-3, steps=200,
        mode="drift", eps0=1.0, a=10.0, move=True):
    xg = lattice(n, 0.0); xd = lattice(n, shift)
    mg = 1.0 / n ** 3; md = eps0 / n ** 3
    h = hfact / n
    nc = max(1, int(np.floor(1.0 / (cfac * h))))
    N = len(xg)
    vg = np.zeros((N, 3)); ud = np.zeros((N, 3)); ag = np.zeros((N, 3))
    if mode == "drift":
        ag[:, 0] = a
    elif mode == "wave":
        A = 1e-3
        vg[:, 0] = A * np.sin(2 * np.pi * xg[:, 0]); ud[:, 0] = A * np.sin(2 * np.pi * xd[:, 0])
    elif mode == "box":
        ud[:, 0] = 1.0
    p0 = mg * vg.sum(0) + md * ud.sum(0)
    for s in range(steps):
        vg, ud = step(scheme, xg, vg, xd, ud, mg, md, tau, ts, ag, nc, order)
        if move:
            xg = (xg + tau * vg) % 1.0; xd = (xd + tau * ud) % 1.0
    p1 = mg * vg.sum(0) + md * ud.sum(0) - tau * steps * mg * ag.sum(0)
    out = {}
    out["mom"] = np.abs(p1 - p0).max()
    if mode == "drift":
        drift_exact = ts * a / (1 + eps0) * (1 - 0)  # steady (discrete BE steady state is same)
        rel = vg[:, 0].mean() - ud[:, 0].mean()
        out["drift_err"] = rel / drift_exact - 1
        out["scat_d"] = ud[:, 0].std() / drift_exact
        out["scat_g"] = vg[:, 0].std() / drift_exact
    elif mode == "wave":
        A = 1e-3
        ag_ = 2 * (vg[:, 0] * np.sin(2 * np.pi * xg[:, 0])).mean() / A
        ad_ = 2 * (ud[:, 0] * np.sin(2 * np.pi * xd[:, 0])).mean() / A
        out["amp_g"] = ag_; out["amp_d"] = ad_
    elif mode == "box":
        # exact BE for uniform: relative x decays by (1+beta(1+eps))^-n; bary = eps/(1+eps)
        beta = tau / ts
        x = -1.0 * (1 + beta * (1 + eps0)) ** (-steps)
        vb = eps0 / (1 + eps0)
        vge = vb + x * eps0 / (1 + eps0); ude = vb - x / (1 + eps0)
        out["err_g"] = np.abs(vg[:, 0] - vge).max(); out["err_d"] = np.abs(ud[:, 0] - ude).max()
    return out

if __name__ == "__main__" and len(sys.argv) == 1:
    for mode, ts, steps in [("box", 0.1, 100), ("wave", 1e-6, 200), ("drift", 1e-6, 200), ("drift", 1e-2, 400), ("drift", 1.0, 400)]:
        for scheme, order, cfac in [("ngp", 0, 0.5), ("pic", 2, 1.0), ("flip", 2, 1.0), ("flip", 1, 1.0), ("flip", 2, 2.0)]:
            for shift in [0.0, 0.5]:
                r = run(scheme, shift=shift, order=order, cfac=cfac, ts=ts, mode=mode, steps=steps)
                print(mode, ts, scheme, order, cfac, shift, {k: f"{v:.3g}" for k, v in r.items()}, flush=True)

from scipy.spatial import cKDTree
from scipy.sparse import csr_matrix

def W3(r, h):
    q = r / h
    f = np.where(q <= 1, 1 - 1.5 * q * q + 0.75 * q ** 3, np.where(q <= 2, 0.25 * (2 - q) ** 3, 0.0))
    return f / (np.pi * h ** 3)

def kmat(xsrc, xdst, h):
    """sparse matrix K[i_src, a_dst] = W(|x_i - x_a|, h), periodic unit box"""
    t = cKDTree(xdst % 1.0, boxsize=1.0)
    pairs = t.query_ball_point(xsrc % 1.0, 2 * h)
    rows = np.repeat(np.arange(len(xsrc)), [len(p) for p in pairs])
    cols = np.concatenate([np.array(p, dtype=int) for p in pairs])
    d = xsrc[rows] - xdst[cols]; d -= np.round(d)
    r = np.sqrt((d * d).sum(1))
    return csr_matrix((W3(r, h), (rows, cols)), shape=(len(xsrc), len(xdst)))

def kernel_solve(xg, vg, xd, ud, mg, md, tau, ts, ag, h):
    """the kernel coupling's deposit and cell solve: (ṽ, weights gas/dust, old and new means, ε)"""
    vt = vg + tau * ag
    Kg = kmat(xg, xg, h); Kd = kmat(xd, xg, h)
    sg = np.asarray(Kg.sum(1)).ravel(); sd = np.asarray(Kd.sum(1)).ravel()
    wg = csr_matrix(Kg.multiply(1 / sg[:, None])); wd = csr_matrix(Kd.multiply(1 / np.maximum(sd, 1e-300)[:, None]))
    Mg = wg.T @ np.full(len(xg), mg); Md = wd.T @ np.full(len(xd), md)
    Vg = (wg.T @ (mg * vt)) / Mg[:, None]; Ud = (wd.T @ (md * ud)) / np.maximum(Md, 1e-300)[:, None]
    eps = Md / Mg
    beta = np.where(Md > 0, tau / ts, 0)
    wf = eps * beta / (1 + beta)
    Vn = (Vg + wf[:, None] * Ud) / (1 + wf)[:, None]
    Un = (Ud + beta[:, None] * Vn) / (1 + beta)[:, None]
    return vt, wg, wd, Vg, Ud, Vn, Un, eps

def step_kernel(xg, vg, xd, ud, mg, md, tau, ts, ag, h):
    """'cells' = gas particles: each particle deposits with W normalised over the gas particles"""
    vt, wg, wd, Vg, Ud, Vn, Un, eps = kernel_solve(xg, vg, xd, ud, mg, md, tau, ts, ag, h)
    return vt + wg @ (Vn - Vg), ud + wd @ (Un - Ud), eps

def run_k(n=16, shift=0.5, hfact=1.2, ts=1e-6, tau=1e-3, steps=200, mode="drift", eps0=1.0, a=10.0, jitter=0.0, seed=1):
    rng = np.random.default_rng(seed)
    xg = (lattice(n, 0.0) + jitter / n * rng.uniform(-0.5, 0.5, (n ** 3, 3))) % 1
    xd = (lattice(n, shift) + jitter / n * rng.uniform(-0.5, 0.5, (n ** 3, 3))) % 1
    mg = 1.0 / n ** 3; md = eps0 / n ** 3; h = hfact / n
    N = len(xg)
    vg = np.zeros((N, 3)); ud = np.zeros((N, 3)); ag = np.zeros((N, 3))
    A = 1e-3
    if mode == "drift": ag[:, 0] = a
    elif mode == "wave":
        vg[:, 0] = A * np.sin(2 * np.pi * xg[:, 0]); ud[:, 0] = A * np.sin(2 * np.pi * xd[:, 0])
    elif mode == "box": ud[:, 0] = 1.0
    p0 = mg * vg.sum(0) + md * ud.sum(0)
    for s in range(steps):
        vg, ud, eps = step_kernel(xg, vg, xd, ud, mg, md, tau, ts, ag, h)
        xg = (xg + tau * vg) % 1.0; xd = (xd + tau * ud) % 1.0
    out = {"eps_spread": eps.std() / eps.mean()}
    out["mom"] = np.abs(mg * vg.sum(0) + md * ud.sum(0) - tau * steps * mg * ag.sum(0) - p0).max()
    if mode == "drift":
        de = ts * a / (1 + eps0)
        out["drift_err"] = (vg[:, 0].mean() - ud[:, 0].mean()) / de - 1
        out["scat_d"] = ud[:, 0].std() / de; out["scat_g"] = vg[:, 0].std() / de
    elif mode == "wave":
        out["amp_g"] = -1 + 2 * (vg[:, 0] * np.sin(2 * np.pi * xg[:, 0])).mean() / A
        out["amp_d"] = -1 + 2 * (ud[:, 0] * np.sin(2 * np.pi * xd[:, 0])).mean() / A
    elif mode == "box":
        beta = tau / ts; x = -1.0 * (1 + beta * (1 + eps0)) ** (-steps); vb = eps0 / (1 + eps0)
        out["err_g"] = np.abs(vg[:, 0] - (vb + x * eps0 / (1 + eps0))).max()
        out["err_d"] = np.abs(ud[:, 0] - (vb - x / (1 + eps0))).max()
    return out

# Reproduce docs/method.md §K: python3 scripts/prototypes/drag_coupling.py kernel [jitter]
if __name__ == "__main__" and len(sys.argv) > 1 and sys.argv[1] == "kernel":
    jit = float(sys.argv[2]) if len(sys.argv) > 2 else 0.0
    for mode, ts, steps in [("box", 0.1, 100), ("wave", 1e-6, 200), ("drift", 1e-6, 100), ("drift", 1e-4, 100), ("drift", 1e-2, 200)]:
        for shift in [0.0, 0.25, 0.5]:
            r = run_k(shift=shift, ts=ts, mode=mode, steps=steps, jitter=jit)
            print("kernel", jit, mode, ts, shift, {k: f"{v:.3g}" for k, v in r.items()}, flush=True)
