#!/usr/bin/env python3
"""How loose is the thin halo's motion bound (docs/scaling.md, "Measured costs")?

Between consecutive snapshots of a one-process run, compares the bound a run over ranks
rebuilds its halo on (2 min(max |d|, half-diagonal of the displacements' box), every particle
alike) with the largest relative displacement |d_i - d_j| of the pairs that actually meet
across a cut: particles on either side of the plane x = median, within R of each other at the
first snapshot. The ratio is what a bound from local (per-cell) displacements could gain at
best.

usage: halo_motion_bound.py OUTPUT_DIR SUPPORT   (SUPPORT = 2h, e.g. 0.0616 for the ball at
       --set sph.h=0.0308; needs h5py, numpy, scipy)
"""
import sys

import h5py
import numpy as np
from scipy.spatial import cKDTree


def positions(path):
    """All particles' positions (gas, then dust), each phase in id order, and the frame's
    extent per axis (the period on a periodic axis)."""
    with h5py.File(path) as f:
        off = f["Header"].attrs.get("CoordinateOffset", np.zeros(3))
        size = f["Header"].attrs["BoxSizePerAxis"]
        out = []
        for group in ("PartType0", "PartType3"):
            if group in f:
                x = f[group]["Coordinates"][:] + off
                out.append(x[np.argsort(f[group]["ParticleIDs"][:])])
    return np.concatenate(out), size


def main():
    out, support = sys.argv[1], float(sys.argv[2])
    k = 0
    while True:
        try:
            x0, size = positions(f"{out}/snapshot_{k:04d}.h5")
            x1, _ = positions(f"{out}/snapshot_{k + 1:04d}.h5")
        except FileNotFoundError:
            break
        # Minimum image: on a periodic axis a particle that crossed the boundary moved by
        # less than half the period (on an open axis the frame is wider than any step's move).
        d = x1 - x0
        d -= size * np.round(d / size)
        largest = np.linalg.norm(d, axis=1).max()
        half = np.linalg.norm(d.max(0) - d.min(0)) / 2
        bound = 2 * min(largest, half)
        cut = np.median(x0[:, 0])
        left = x0[:, 0] < cut
        right = np.where(~left)[0]
        tree = cKDTree(x0[right])
        for reach in (1.5 * support, 3.0 * support):
            near = np.where(left & (x0[:, 0] > cut - reach))[0]
            worst = 0.0
            for i, js in zip(near, tree.query_ball_point(x0[near], reach)):
                if js:
                    rel = np.linalg.norm(d[right[js]] - d[i], axis=1).max()
                    worst = max(worst, rel)
            print(
                f"snapshots {k}->{k + 1}: bound {bound / support:.2f} supports; pairs across "
                f"the cut within {reach / support:.1f} supports: largest |d_i - d_j| "
                f"{worst / support:.2f} supports"
            )
        k += 1


if __name__ == "__main__":
    main()
