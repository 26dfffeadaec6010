"""Vertical settling in a 3D disc snapshot (docs/method.md §D): per dust fraction, in an annulus
and bands of |z|/H, the mass-weighted slope of the dust's v_z (less the gas's slope in the same
band) against z, over the exact settling mode's λ (ż = λz, λ = (√(1 − 4Ω_z²t²) − 1)/(2t), the
slow root of z̈ = −Ω_z² z − ż/t; ≈ −Ω St; none for St ≥ ½, printed nan). 1 is right. A unit
point mass at the origin (G = M = 1), c_s = cs0 (R/r_ref)^-q, H = c_s/Ω. Needs numpy and h5py.
    python3 scripts/disc_settling.py SNAPSHOT CS0 R_REF [Q] [R_LO R_HI]
Q: 0.25; R_LO, R_HI: 0.5 r_ref and 2 r_ref."""
import sys

import h5py
import numpy as np

path, cs0, r_ref = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
q = float(sys.argv[4]) if len(sys.argv) > 4 else 0.25
lo_r, hi_r = (float(sys.argv[5]), float(sys.argv[6])) if len(sys.argv) > 6 else (0.5 * r_ref, 2 * r_ref)

with h5py.File(path) as f:
    off = f["Header"].attrs["CoordinateOffset"]
    xg, vg, mg = (f["PartType0/" + k][:] for k in ("Coordinates", "Velocities", "Masses"))
    xd, vd, md = (f["PartType3/" + k][:] for k in ("Coordinates", "Velocities", "Masses"))
    frac, ts = f["PartType3/FractionIndex"][:], f["PartType3/StoppingTime"][:]
    xg, xd = xg + off, xd + off


def band(x, a, b):
    r = np.hypot(x[:, 0], x[:, 1])
    h = cs0 * (r / r_ref) ** -q * r**1.5
    z = np.abs(x[:, 2]) / h
    return (r > lo_r) & (r < hi_r) & (z >= a) & (z < b)


for a, b in [(0.25, 0.75), (0.75, 1.25)]:
    g = band(xg, a, b)
    gas = np.sum(mg[g] * vg[g, 2] * xg[g, 2]) / np.sum(mg[g] * xg[g, 2] ** 2)
    line = f"|z|/H {a}-{b}: gas v_z/z {gas:+.2e}"
    for k in range(frac.max() + 1):
        s = band(xd, a, b) & (frac == k)
        r, z, t, w = np.hypot(xd[s, 0], xd[s, 1]), xd[s, 2], ts[s], md[s]
        disc = 1 - 4 * t * t / (r * r + z * z) ** 1.5
        lam = np.where(disc > 0, (np.sqrt(np.maximum(disc, 0)) - 1) / (2 * t), np.nan)
        meas = np.sum(w * (vd[s, 2] - gas * z) * z) / np.sum(w * z * z)
        exact = np.sum(w * lam * z * z) / np.sum(w * z * z)
        line += f" | fraction {k}: {meas / exact:.3f}"
    print(line)
