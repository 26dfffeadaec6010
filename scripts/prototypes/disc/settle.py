"""Vertical settling in a 3D disc snapshot: in bands of |z|/H (R 0.9-1.2), the gas's mean v_z sgn z
and each dust fraction's, their difference, and the exact settling mode's
lambda z, lambda = (sqrt(1 - 4 Omega_z^2 t^2) - 1)/(2t). Needs numpy and h5py.
    python3 scripts/prototypes/disc/settle.py SNAPSHOT T_STOPS [H]
T_STOPS: the fractions' stopping times, comma-separated; H: the scale height at R = 1 (0.1)."""
import h5py, numpy as np, sys
f = h5py.File(sys.argv[1]); off = f["Header"].attrs["CoordinateOffset"]
ts = [float(x) for x in sys.argv[2].split(',')]
g=f["PartType0"]; d=f["PartType3"]
xg=g["Coordinates"][:]+off; vg=g["Velocities"][:]; xd=d["Coordinates"][:]+off; vd=d["Velocities"][:]; fi=d["FractionIndex"][:]; md=d["Masses"][:]; mg=g["Masses"][:]
Rg=np.hypot(xg[:,0],xg[:,1]); Rd=np.hypot(xd[:,0],xd[:,1])
lo,hi=0.9,1.2
selg=(Rg>lo)&(Rg<hi)
H=float(sys.argv[3]) if len(sys.argv)>3 else 0.1
for zlo,zhi in [(0.25,0.75),(0.75,1.25),(1.25,2.0)]:
    line=f"|z|/H {zlo}-{zhi}:"
    sg=selg&(np.abs(xg[:,2])/H>zlo)&(np.abs(xg[:,2])/H<zhi)
    gz=np.average(vg[sg,2]*np.sign(xg[sg,2]),weights=mg[sg])
    line+=f" gas v_z·sgn z {gz:+.2e}"
    for k,t in enumerate(ts):
        s=(Rd>lo)&(Rd<hi)&(fi==k)&(np.abs(xd[:,2])/H>zlo)&(np.abs(xd[:,2])/H<zhi)
        R=Rd[s]; z=xd[s,2]; oz2=(R*R+z*z)**-1.5; exact=np.abs(z)*(np.sqrt(1-4*oz2*t*t)-1)/(2*t)
        w=md[s]
        v=np.average(vd[s,2]*np.sign(z),weights=w); e=np.average(exact,weights=w)
        rel=np.average((vd[s,2]-0)*np.sign(z),weights=w)-gz
        line+=f" | t_s {t}: v_z {v:+.3e} rel {rel:+.3e} exact {e:+.3e} ({rel/e-1:+.1%})"
    print(line)
