"""Velocity dispersion in a 2D disc snapshot, R 1.1-1.3: the rms of v_R of the gas and of each of
three dust fractions, and of each dust particle's v_R less the gas's SPH-interpolated at it (what
the drag acts on). Needs numpy, h5py and scipy.
    python3 scripts/prototypes/disc/dispersion.py SNAPSHOT [SNAPSHOT ...]"""
import h5py, numpy as np, sys
from scipy.spatial import cKDTree
def W(q): return np.where(q<1, 1-1.5*q**2+0.75*q**3, np.where(q<2, 0.25*(2-q)**3, 0))
for fn in sys.argv[1:]:
    f = h5py.File(fn); off = f["Header"].attrs["CoordinateOffset"]
    g=f["PartType0"]; d=f["PartType3"]
    xg=g["Coordinates"][:,:2]+off[:2]; vg=g["Velocities"][:,:2]; mg=g["Masses"][:]; rhog=g["Density"][:]; hg=g["SmoothingLength"][:]
    xd=d["Coordinates"][:,:2]+off[:2]; vd=d["Velocities"][:,:2]; fi=d["FractionIndex"][:]
    Rg=np.hypot(*xg.T); Rd=np.hypot(*xd.T)
    tree=cKDTree(xg)
    def interp(x, hs):
        out=np.zeros((len(x),2))
        for i in range(len(x)):
            idx=tree.query_ball_point(x[i], hs[i]); r=np.linalg.norm(xg[idx]-x[i],axis=1); w=W(2*r/hs[i])*mg[idx]/rhog[idx]
            out[i]=(w[:,None]*vg[idx]).sum(0)/w.sum()
        return out
    def radial(x,v): R=np.hypot(*x.T); return (x[:,0]*v[:,0]+x[:,1]*v[:,1])/R
    selg=(Rg>1.1)&(Rg<1.3)
    gi=interp(xg[selg], hg[selg])
    line=f"{fn[-8:]}: gas vR sd {radial(xg[selg],vg[selg]).std():.1e}, vs own smoothed {radial(xg[selg],vg[selg]-gi).std():.1e}"
    tree_d=cKDTree(xg)
    for k in range(3):
        sel=(Rd>1.1)&(Rd<1.3)&(fi==k)
        hs=np.full(sel.sum(), np.median(hg[selg]))
        di=interp(xd[sel], hs)
        line+=f" | dust{k} vR sd {radial(xd[sel],vd[sel]).std():.1e} rel sd {radial(xd[sel],vd[sel]-di).std():.1e}"
    print(line)
