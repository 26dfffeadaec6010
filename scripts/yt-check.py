#!/usr/bin/env python3
"""yt reads dustsph snapshots where they are: a committed check (issue 13), not run in CI (it
needs `pip install yt h5py`).

Runs two short scenes with the binary given (default target/release/dustsph): the 3D ball
(open, centred at the origin) and the 3D Phantom slab (periodic, 1 x 0.32 x 0.27), loads their
t = 0 snapshots with yt's GADGET frontend and checks
  - yt's domain is the file's box: [0, BoxSize)³ for the ball by default, and the slab's
    own extent (Header/BoxSizePerAxis) when loaded with that bounding_box;
  - yt's SPH density at points inside the ball, including the negative octant
    (-0.3, -0.3, -0.3), and inside the slab equals dustsph's own density there (the
    particles' `Density`, interpolated the SPH way with yt's own kernel) to 2 %;
  - the smoothing length yt uses is the kernel support (SmoothingLength = 2h);
  - a run in au and solar masses ([units]) loads in physical units: yt's code length, mass
    and time are 1 au, 1 M_sun and the file's UnitTime_in_s, and densities convert to g/cm^3.
Prints one line per check; exit 1 if any fails.
    scripts/yt-check.py [BINARY]
"""
import subprocess
import sys
import tempfile

import h5py
import numpy as np
import yt

yt.set_log_level(50)
bin_ = sys.argv[1] if len(sys.argv) > 1 else "target/release/dustsph"
fails = 0


def check(ok, what):
    global fails
    print(("ok   " if ok else "FAIL ") + what)
    fails += 0 if ok else 1


def run(scene, sets, out):
    cmd = [bin_, "run", scene, "--device", "cpu", "--out", out, "--force", "-q"]
    for s in sets:
        cmd += ["--set", s]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return out + "/snapshot_0000.h5"


def sph_density_at(ds, point):
    """yt's own SPH slice of the gas density through `point` (normal z), read at the point."""
    point = np.asarray(point, dtype=float)
    p = yt.SlicePlot(ds, "z", ("gas", "density"), center=ds.arr(point, "code_length"),
                     width=ds.quan(0.05, "code_length"), buff_size=(5, 5))
    return float(p.frb[("gas", "density")].in_units("code_mass/code_length**3").d[2, 2])


with tempfile.TemporaryDirectory() as tmp:
    # The ball: ρ_g = 1 inside radius 1, centred at the origin (open axes).
    snap = run("configs/dusty_ball.toml", ["sph.n=16", "time.t_end=0.005", "time.dt=0.005"], tmp + "/ball")
    with h5py.File(snap) as f:
        off = f["Header"].attrs["CoordinateOffset"]
        box = f["Header"].attrs["BoxSize"]
        sl = f["PartType0/SmoothingLength"][:]
        per_axis = f["Header"].attrs["BoxSizePerAxis"]
        per_h = f["Header"].attrs["SmoothingLengthPerH"]
    ds = yt.load(snap)
    check(np.allclose(ds.domain_left_edge.d, 0) and np.allclose(ds.domain_right_edge.d, box)
          and np.allclose(per_axis, box),
          f"ball: yt's domain (default load) is the file's box [0, {box:.4f})^3")
    ad = ds.all_data()
    hsml = ad[("PartType0", "smoothing_length")].d
    check(np.allclose(hsml, sl) and per_h == 2.0,
          f"ball: yt's smoothing length is SmoothingLength = 2h ({hsml.mean():.4f})")
    for p in [(0.0, 0.0, 0.0), (-0.3, -0.3, -0.3), (0.3, -0.2, 0.1)]:
        rho = sph_density_at(ds, np.array(p) - off)
        check(abs(rho - 1.0) < 0.02, f"ball: yt's SPH density at {p} = {rho:.4f} (dustsph: 1)")
    # The Phantom slab: periodic 1 x 0.32 x 0.27 (rounded to whole close-packed rows).
    snap = run("configs/dustywave_phantom.toml", ["time.t_end=0.001", "time.output_dt="], tmp + "/slab")
    with h5py.File(snap) as f:
        off = f["Header"].attrs["CoordinateOffset"]
        box = f["Header"].attrs["BoxSizePerAxis"]
        rho_mean = f["PartType0/Density"][:].mean()
    # A non-cubic box: GADGET's one BoxSize cannot say it; yt's bounding_box can (README).
    ds = yt.load(snap, bounding_box=[[0, box[0]], [0, box[1]], [0, box[2]]])
    check(np.allclose(ds.domain_right_edge.d - ds.domain_left_edge.d, box) and box[1] < 0.5,
          f"slab: yt's domain is the slab, {np.round(ds.domain_width.d, 4)}")
    for p in [(0.25, 0.05, 0.05), (0.8, 0.1, 0.12)]:
        rho = sph_density_at(ds, np.array(p) - off)
        check(abs(rho - rho_mean) < 0.02 * rho_mean,
              f"slab: yt's SPH density at {p} = {rho:.4f} (dustsph mean {rho_mean:.4f})")
    # Physical units ([units], docs/scenes.md): yt's GADGET frontend takes them as `unit_base`,
    # read here from the Header attributes the snapshot carries (UnitLength_in_cm, ...).
    snap = run("configs/dusty_ball.toml",
               ["sph.n=16", "time.t_end=0.005", "time.dt=0.005", 'units.length="au"',
                'units.mass="msun"'], tmp + "/ball_au")
    with h5py.File(snap) as f:
        hdr = f["Header"].attrs
        base = {k: float(hdr[k]) for k in
                ["UnitLength_in_cm", "UnitMass_in_g", "UnitVelocity_in_cm_per_s"]}
        t_unit = float(hdr["UnitTime_in_s"])
        rho_code = f["PartType0/Density"][:]
    ds = yt.load(snap, unit_base=base)
    check(abs(float(ds.length_unit.to("au").d) - 1.0) < 1e-9,
          f"units: yt's code length is 1 au ({ds.length_unit.to('cm')})")
    check(abs(float(ds.mass_unit.to("Msun").d) - 1.0) < 1e-3,
          f"units: yt's code mass is 1 M_sun ({ds.mass_unit.to('g')})")
    check(abs(float(ds.time_unit.to("s").d) / t_unit - 1.0) < 1e-9,
          f"units: yt's code time is the file's UnitTime_in_s = sqrt(L^3/(G M)) ({t_unit:.4e} s)")
    rho_yt = ds.all_data()[("PartType0", "Density")].to("g/cm**3").d
    want = rho_code * base["UnitMass_in_g"] / base["UnitLength_in_cm"] ** 3
    check(np.allclose(np.sort(rho_yt), np.sort(want), rtol=1e-10),
          f"units: yt's gas density in g/cm^3 is Density x M/L^3 ({want.mean():.3e})")
sys.exit(1 if fails else 0)
