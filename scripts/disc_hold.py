"""How well a gas disc holds (docs/method.md §D, "The discs' edges"): for each snapshot of a
run, per annulus, the change of Sigma relative to the first snapshot (2D: the particles'
mass-weighted SPH density; 3D: the annulus's mass over its area), the change of the
mass-weighted rotation v_phi relative to the first snapshot's (over the local c_s), and the rms
over the particles of the gas's v_R over the local c_s = cs0 (R/r_ref)^-q. Times in orbits at
r_ref (GM = 1). Needs numpy and h5py.
    python3 scripts/disc_hold.py RUN_DIR [EDGES] [CS0] [Q] [R_REF] [DIM]
EDGES: annulus edges, comma-separated (0.5,0.6,0.8,1.1,1.5,2); CS0 (0.05); Q (0.25); R_REF (1);
DIM (2)."""
import glob
import sys

import h5py
import numpy as np

run = sys.argv[1]
edges = np.array([float(e) for e in (sys.argv[2] if len(sys.argv) > 2 else "0.5,0.6,0.8,1.1,1.5,2").split(",")])
cs0 = float(sys.argv[3]) if len(sys.argv) > 3 else 0.05
q = float(sys.argv[4]) if len(sys.argv) > 4 else 0.25
r_ref = float(sys.argv[5]) if len(sys.argv) > 5 else 1.0
dim = int(sys.argv[6]) if len(sys.argv) > 6 else 2
orbit = 2 * np.pi * r_ref**1.5


def annuli(path):
    with h5py.File(path) as f:
        t = f["Header"].attrs["Time"]
        x = f["PartType0/Coordinates"][:] + f["Header"].attrs["CoordinateOffset"]
        v = f["PartType0/Velocities"][:]
        m = f["PartType0/Masses"][:]
        rho = f["PartType0/Density"][:]
    r = np.hypot(x[:, 0], x[:, 1])
    vr = (x[:, 0] * v[:, 0] + x[:, 1] * v[:, 1]) / r
    vphi = (x[:, 0] * v[:, 1] - x[:, 1] * v[:, 0]) / r
    mass = np.histogram(r, edges, weights=m)[0]
    if dim == 3:
        sigma = mass / (np.pi * (edges[1:] ** 2 - edges[:-1] ** 2))
    else:
        sigma = np.histogram(r, edges, weights=m * rho)[0] / np.maximum(mass, 1e-300)
    count = np.histogram(r, edges)[0]
    cs = cs0 * (r / r_ref) ** -q
    stir = np.sqrt(np.histogram(r, edges, weights=(vr / cs) ** 2)[0] / np.maximum(count, 1))
    rot = np.histogram(r, edges, weights=m * vphi)[0] / np.maximum(mass, 1e-300)
    mid = 0.5 * (edges[:-1] + edges[1:])
    return float(np.atleast_1d(t)[0]), sigma, stir, rot / (cs0 * (mid / r_ref) ** -q)


files = sorted(glob.glob(run + "/snapshot_*.h5"))
_, sigma0, _, rot0 = annuli(files[0])
print("annuli:", " ".join(f"{a:g}-{b:g}" for a, b in zip(edges[:-1], edges[1:])))
for path in files:
    t, sigma, stir, rot = annuli(path)
    print(
        f"orbits {t / orbit:6.3f}  dSigma % " + " ".join(f"{100 * (s / s0 - 1):+6.1f}" for s, s0 in zip(sigma, sigma0)),
        " | rms vR/cs " + " ".join(f"{s:6.3f}" for s in stir),
        " | dvphi/cs " + " ".join(f"{a - b:+6.3f}" for a, b in zip(rot, rot0)),
    )
