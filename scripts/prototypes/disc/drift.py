"""Mass-weighted radial velocities of the gas and each dust fraction of a snapshot of
configs/dustydisc.toml in radial bins, against the exact steady drift (the same balances as
host/exact/drift.rs, solved for the drag accelerations). Needs numpy and h5py.
    TS=0.01,0.1,1.0 python3 scripts/prototypes/disc/drift.py output/dustydisc/snapshot_0004.h5
The disc's parameters below are the shipped scene's; TS lists the fractions' stopping times.
Prints per bin the gas's v_R, and per fraction its v_R and its drift relative to the gas
(its mean less the gas's) against the exact relative drift."""
import h5py, numpy as np, sys, os
TS = [float(x) for x in os.environ.get("TS", "0.01,0.1,1.0").split(",")]
f = h5py.File(sys.argv[1]); off = f["Header"].attrs["CoordinateOffset"]
cs0, q, p, rin = 0.05, 0.25, 1.0, 0.5
def exact(R, eps, st):
    # NSH-like multi-species via the same balances (numpy)
    n = len(eps); m = 2*n+2; A = np.zeros((m,m)); b = np.zeros(m)
    A[0,1] = 2; b[0] = -2; A[1,0] = -0.5
    for j in range(n):
        ar, ap = 2+2*j, 3+2*j
        A[0,ar] = eps[j]; A[1,ap] = eps[j]
        A[ar,1] = 2; A[ar,ap] = 2*st[j]; A[ar,ar] = -1
        A[ap,0] = -0.5; A[ap,ar] = -0.5*st[j]; A[ap,ap] = -1
    x = np.linalg.solve(A, b)
    return x[0], [x[0] + st[j]*x[2+2*j] for j in range(n)]
def vr(g):
    x = f[g]["Coordinates"][:] + off; v = f[g]["Velocities"][:]; m = f[g]["Masses"][:]
    R = np.hypot(x[:,0], x[:,1]); vR = (x[:,0]*v[:,0] + x[:,1]*v[:,1])/R
    return R, vR, m, (f[g]["FractionIndex"][:] if "FractionIndex" in f[g] else None)
Rg, vg, mg, _ = vr("PartType0"); Rd, vd, md, fi = vr("PartType3")
for lo, hi in [(0.8, 0.9), (0.95, 1.05), (1.1, 1.3), (1.3, 1.6)]:
    Rc = 0.5*(lo+hi); vk = Rc**-0.5; c = cs0*Rc**-q
    s = np.sqrt(rin/Rc); dlnp = -2*q - p + 0.5*s/(1-s); eta = -0.5*c*c/vk*dlnp
    om = Rc**-1.5; st = [om*t for t in TS]
    g_ex, d_ex = exact(Rc, [0.01]*len(TS), st)
    sel = (Rg > lo) & (Rg < hi); gv = np.average(vg[sel], weights=mg[sel])
    line = f"R {lo}-{hi}: gas vR {gv:+.2e} (exact {g_ex*eta:+.2e}, scatter {vg[sel].std():.1e})"
    for k in range(len(TS)):
        sel = (Rd > lo) & (Rd < hi) & (fi == k)
        dv = np.average(vd[sel], weights=md[sel]); ex = (d_ex[k]-g_ex)*eta
        line += f" | St {st[k]:.3g}: {dv:+.2e}, rel {dv-gv:+.2e} vs {ex:+.2e} ({(dv-gv)/ex-1:+.0%})"
    print(line)
