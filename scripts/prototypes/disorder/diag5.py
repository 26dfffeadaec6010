"""decompose the drift error: cell-level relative velocity vs co-moving covariance; local (interpolated) drift"""
import sys, time, numpy as np
from sim import Sim, kmat
import schemes as S
jit = float(sys.argv[1])
for t in [1e-6, 1e-4]:
    s = Sim(n=12, jitter=jit, fracs=((0.5, t), (1.0, 0.05)))
    g = 10 / 2.5
    for k in range(100):
        d = s.step(S.kernel)
        if k % 25 == 24:
            Mg, Mk, Vn, Un, eps = d["Mg"], d["Mk"], d["Vn"][:, 0], [u[:, 0] for u in d["Un"]], d["eps"]
            mu = Mg / Mg.sum(); nu = Mk[0] / Mk[0].sum()
            cell_rel = (nu * (Vn - Un[0])).sum() / (t * g) - 1
            cov = ((mu - nu) * Vn).sum() / (t * g)
            # local drift: gas velocity interpolated (Shepard, gas kernel) at each dust particle minus its velocity
            Rd = kmat(s.xd[0], s.xg, s.h)
            loc = ((Rd @ s.vg[:, 0]) - s.ud[0][:, 0]).mean() / (t * g) - 1
            var_e = (mu * (eps[0] - 0.5) ** 2).sum()
            pred = 10 * s.t * var_e / (0.5 * 2.5 ** 2) / (t * g)
            print(f"t {t:.0e} jit {jit} time {s.t:.2f}: particle err {s.drift()[0]:+.3e} = cell-rel {cell_rel:+.2e} + cov {cov:+.3e};"
                  f" local-drift err {loc:+.2e}; var(eps)={var_e:.2e} (sd/eps {np.sqrt(var_e)/0.5:.3f}); a*time*var/(eps(1+E)^2)/drift={pred:.3e}", flush=True)
