"""Drag-step prototypes for dustsph's kernel coupling on disordered particles.
3D periodic unit box, gas + N dust fractions, optional isothermal SPH pressure (fixed h, M4).
Schemes live in schemes.py; this file holds geometry, pressure, the cell solve and the runner."""
import numpy as np
from scipy.spatial import cKDTree
from scipy.sparse import csr_matrix

SIG = 1.0 / np.pi


def W(r, h):
    q = r / h
    a = np.maximum(2 - q, 0.0); b = np.maximum(1 - q, 0.0)
    return (SIG / h ** 3) * (0.25 * a * a * a - b * b * b)


def dWr(r, h):
    """(dW/dr)/r, so grad_a W_ab = dWr * (x_a - x_b)"""
    q = r / h
    a = np.maximum(2 - q, 0.0); b = np.maximum(1 - q, 0.0)
    return (SIG / h ** 5) * (-0.75 * a * a + 3 * b * b) / np.maximum(q, 1e-12)


def lattice(n, shift=0.0):
    g = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    return (np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1) + shift / n) % 1.0


def pairs(xs, xd, h):
    """all (i in xs, a in xd) with r < 2h, periodic: i, a, dx = x_i - x_a (min image), r"""
    ts = cKDTree(xs % 1.0, boxsize=1.0); td = cKDTree(xd % 1.0, boxsize=1.0)
    p = ts.sparse_distance_matrix(td, 2 * h, output_type="ndarray")
    i, a = p["i"], p["j"]
    dx = xs[i] - xd[a]; dx -= np.round(dx)
    return i, a, dx, np.sqrt((dx * dx).sum(1))


class NL:
    """Verlet pair list with a skin; valid while every particle moved < skin/2 relative to the gas mean"""
    def __init__(self, skin):
        self.skin, self.lists, self.cache = skin, {}, {}

    def get(self, key, xs, xd, h, ref):
        c = self.cache.get(key)
        if c is not None and c[0] is xs and c[1] is xd:
            return c[2]
        res = self._get(key, xs, xd, h, ref)
        self.cache[key] = (xs, xd, res)
        return res

    def _get(self, key, xs, xd, h, ref):
        L = self.lists.get(key)
        if L is not None:
            (xs0, xd0, ref0, i, a) = L
            sh = ref - ref0; sh -= np.round(sh)
            ds = xs - xs0 - sh; ds -= np.round(ds); dd = xd - xd0 - sh; dd -= np.round(dd)
            m = max(np.sqrt((ds * ds).sum(1)).max(), np.sqrt((dd * dd).sum(1)).max())
            if m > self.skin / 2:
                L = None
        if L is None:
            ts = cKDTree(xs % 1.0, boxsize=1.0); td = cKDTree(xd % 1.0, boxsize=1.0)
            p = ts.sparse_distance_matrix(td, 2 * h + self.skin, output_type="ndarray")
            L = (xs.copy(), xd.copy(), ref.copy(), p["i"], p["j"])
            self.lists[key] = L
        i, a = L[3], L[4]
        dx = xs[i] - xd[a]; dx -= np.round(dx)
        r = np.sqrt((dx * dx).sum(1))
        return i, a, dx, r


NLIST = None


def pairs_c(xs, xd, h, key):
    if NLIST is None or key is None:
        return pairs(xs, xd, h)
    return NLIST.get(key, xs, xd, h, REF[0])


REF = [np.zeros(3)]


def kmat(xs, xd, h, norm=True, key=None):
    i, a, dx, r = pairs_c(xs, xd, h, key)
    K = csr_matrix((W(r, h), (i, a)), shape=(len(xs), len(xd)))
    if not norm:
        return K
    s = np.asarray(K.sum(1)).ravel()
    return csr_matrix(K.multiply(1 / np.maximum(s, 1e-300)[:, None]))


def pressure_acc(xg, mg, h, cs, key=None):
    i, a, dx, r = pairs_c(xg, xg, h, key)
    rho = np.bincount(i, mg * W(r, h), minlength=len(xg))
    P = cs * cs / rho  # p/rho^2 = cs^2/rho
    f = -(mg * (P[i] + P[a]) * dWr(r, h))[:, None] * dx
    acc = np.stack([np.bincount(i, f[:, d], minlength=len(xg)) for d in range(3)], 1)
    return acc, rho


def cell_solve(Vt, U, eps, beta):
    """closed-form implicit multi-fraction solve on each cell; Vt (Nc,3), U list of (Nc,3)"""
    wf = [e * b / (1 + b) for e, b in zip(eps, beta)]
    num = Vt + sum(w[:, None] * u for w, u in zip(wf, U))
    Vn = num / (1 + sum(wf))[:, None]
    Un = [(u + b[:, None] * Vn) / (1 + b)[:, None] for u, b in zip(U, beta)]
    return Vn, Un


class Sim:
    def __init__(self, n=16, nd=None, jitter=0.0, shift=0.0, fracs=((0.5, 1e-6), (1.0, 0.05)), tau=0.01,
                 a=10.0, pressure=True, cs=1.0, hfact=1.2, seed=1, mode="drift", move=True):
        rng = np.random.default_rng(seed)
        nd = nd or n
        self.n, self.h, self.tau, self.a, self.cs, self.pressure, self.mode, self.move = n, hfact / n, tau, a, cs, pressure, mode, move
        self.xg = (lattice(n) + jitter / n * rng.uniform(-1, 1, (n ** 3, 3))) % 1.0
        self.mg = 1.0 / n ** 3
        self.eps0 = [f[0] for f in fracs]; self.ts = [f[1] for f in fracs]
        self.xd = [(lattice(nd, shift) + jitter / nd * rng.uniform(-1, 1, (nd ** 3, 3))) % 1.0 for _ in fracs]
        self.md = [e / nd ** 3 for e in self.eps0]
        Ng = n ** 3
        self.vg = np.zeros((Ng, 3)); self.ud = [np.zeros((nd ** 3, 3)) for _ in fracs]
        self.aext = np.zeros(3)
        if mode == "drift":
            self.aext[0] = a
        elif mode == "wave":
            A = 1e-3
            self.vg[:, 0] = A * np.sin(2 * np.pi * self.xg[:, 0])
            for x, u in zip(self.xd, self.ud):
                u[:, 0] = A * np.sin(2 * np.pi * x[:, 0])
        elif mode == "box":
            for k, u in enumerate(self.ud):
                u[:, 0] = 1.0 + k
        self.p0 = self.momentum()
        self.t = 0.0
        self.hist = []
        global NLIST
        NLIST = NL(0.25 * self.h); REF[0] = np.zeros(3)

    def momentum(self):
        return self.mg * self.vg.sum(0) + sum(m * u.sum(0) for m, u in zip(self.md, self.ud))

    def step(self, scheme):
        tau = self.tau
        acc = np.zeros_like(self.vg)
        if self.pressure:
            acc, _ = pressure_acc(self.xg, self.mg, self.h, self.cs, key="gg")
        vt = self.vg + tau * (acc + self.aext)
        ut = [u.copy() for u in self.ud]
        self.vg, self.ud, diag = scheme(self, vt, ut)
        if self.move:
            self.xg = (self.xg + tau * self.vg) % 1.0
            self.xd = [(x + tau * u) % 1.0 for x, u in zip(self.xd, self.ud)]
        self.t += tau
        REF[0] = REF[0] + tau * self.vg.mean(0)
        return diag

    def drift(self):
        g = self.aext[0] / (1 + sum(self.eps0))
        vbar = self.vg[:, 0].mean()
        return [((vbar - u[:, 0].mean()) / (t * g) - 1) for u, t in zip(self.ud, self.ts)]

    def run(self, scheme, steps, avg_from=None):
        avg_from = steps * 3 // 4 if avg_from is None else avg_from
        acc = []
        for s in range(steps):
            self.step(scheme)
            if self.mode == "drift" and s >= avg_from:
                acc.append(self.drift())
        out = {}
        tot_in = self.mg * len(self.vg) * self.aext * self.t
        out["mom"] = np.abs(self.momentum() - self.p0 - tot_in).max()
        if self.mode == "drift":
            g = self.aext[0] / (1 + sum(self.eps0))
            out["err_end"] = self.drift()
            out["err_avg"] = list(np.mean(acc, 0))
            out["sd_g"] = self.vg[:, 0].std()
            out["sd_d"] = [u[:, 0].std() for u in self.ud]
        elif self.mode == "wave":
            A = 1e-3
            out["amp_g"] = 2 * (self.vg[:, 0] * np.sin(2 * np.pi * self.xg[:, 0])).mean() / A
            out["amp_d"] = [2 * (u[:, 0] * np.sin(2 * np.pi * x[:, 0])).mean() / A for x, u in zip(self.xd, self.ud)]
        elif self.mode == "box":
            # discrete oracle: the cell solve iterated on the global means
            V = np.zeros((1, 3)); U = [np.zeros((1, 3)) + [1.0 + k, 0, 0] for k in range(len(self.ud))]
            for s in range(steps):
                V, U = cell_solve(V, U, [np.array([e]) for e in self.eps0], [np.array([self.tau / t]) for t in self.ts])
            out["err_box"] = max(np.abs(self.vg - V).max(), max(np.abs(u - Uk).max() for u, Uk in zip(self.ud, U)))
        return out
