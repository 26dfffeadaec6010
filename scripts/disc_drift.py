"""The dust's drift against the gas's own motion (docs/method.md §K, "Sampling offsets"): for
each snapshot of a disc run about a unit point mass at the origin (G = M = 1), per dust
fraction, the mass-weighted u_R - v_R summed over radial bins, over the same sum of what a grain
of Stokes number St = Omega t_s in steady drift through that gas must have,
(2 St v_phi' - St^2 v_R)/(1 + St^2) with v_phi' = v_phi - v_K (the gas's own rotation deficit),
and, where the neighbouring snapshots give the gas's dv_R/dt, St (2 v_phi' - (dv_R/dt)/Omega)
/(1 + St^2) (the gas's epicycles added). 1 is right. No pressure gradient is estimated: this is
the coupling alone. Every particle counts (a 2D disc; in 3D the mid-disc's velocities differ
from the column's). Needs numpy and h5py.
    python3 scripts/disc_drift.py RUN_DIR [R_LO R_HI BINS] [EVERY]
R_LO, R_HI, BINS: 1.0 1.6 6; EVERY: print every EVERY-th snapshot (1)."""
import glob
import sys

import h5py
import numpy as np

run = sys.argv[1]
lo, hi, nb = (float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])) if len(sys.argv) > 4 else (1.0, 1.6, 6)
every = int(sys.argv[5]) if len(sys.argv) > 5 else 1
edges = np.linspace(lo, hi, nb + 1)
mid = 0.5 * (edges[1:] + edges[:-1])
omega = mid**-1.5


def cylindrical(f, part):
    x = f[part + "/Coordinates"][:] + f["Header"].attrs["CoordinateOffset"]
    v = f[part + "/Velocities"][:]
    r = np.hypot(x[:, 0], x[:, 1])
    vr = (x[:, 0] * v[:, 0] + x[:, 1] * v[:, 1]) / r
    vphi = (x[:, 0] * v[:, 1] - x[:, 1] * v[:, 0]) / r - r**-0.5
    return r, vr, vphi, f[part + "/Masses"][:]


def binned(r, m, y):
    w = np.histogram(r, edges, weights=m)[0]
    return np.histogram(r, edges, weights=m * y)[0] / w


def snapshot(path):
    with h5py.File(path) as f:
        t = float(np.atleast_1d(f["Header"].attrs["Time"])[0])
        rg, vrg, vpg, mg = cylindrical(f, "PartType0")
        rd, vrd, _, md = cylindrical(f, "PartType3")
        frac = f["PartType3/FractionIndex"][:]
        ts = f["PartType3/StoppingTime"][:]
    gas = (binned(rg, mg, vrg), binned(rg, mg, vpg))
    dust = []
    for k in range(frac.max() + 1):
        s = frac == k
        dust.append((binned(rd[s], md[s], vrd[s]), binned(rd[s], md[s], ts[s]) * omega))
    return t, gas, dust


snaps = [snapshot(p) for p in sorted(glob.glob(run + "/snapshot_*.h5"))]
for i in range(0, len(snaps), every):
    t, (vr, vp), dust = snaps[i]
    dvdt = None
    if 0 < i < len(snaps) - 1:
        (ta, ga, _), (tb, gb, _) = snaps[i - 1], snaps[i + 1]
        dvdt = (gb[0] - ga[0]) / (tb - ta)
    line = f"t {t:9.4f}"
    for k, (ur, st) in enumerate(dust):
        rel = np.sum(ur - vr)
        rot = np.sum((2 * st * vp - st * st * vr) / (1 + st * st))
        line += f" | fraction {k}: {rel / rot:.3f}"
        if dvdt is not None:
            epi = np.sum(st * (2 * vp - dvdt / omega) / (1 + st * st))
            line += f" ({rel / epi:.3f})"
    print(line)
