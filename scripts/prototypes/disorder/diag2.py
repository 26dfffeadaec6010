import sys, time, numpy as np
from sim import Sim
import schemes as S
for name, sch, kw in [("kernel tau=0.005 t1e-4", S.kernel, dict(tau=0.005, fracs=((0.5, 1e-4), (1.0, 0.05)))),
                      ("kernel tau=0.01 t1e-4 single frac", S.kernel, dict(fracs=((0.5, 1e-4),))),
                      ("epsglobal t1e-6", S.kernel_epsglobal, dict(fracs=((0.5, 1e-6), (1.0, 0.05)))),
                      ("epsglobal t1e-6 P0", S.kernel_epsglobal, dict(fracs=((0.5, 1e-6), (1.0, 0.05)), pressure=False)),
                      ]:
    t0 = time.time()
    steps = 60 if kw.get("tau", 0.01) == 0.01 else 120
    s = Sim(n=12, jitter=0.2, **kw)
    r = s.run(sch, steps)
    print(f"{name:34s} err {r['err_end']} avg {r['err_avg'][0]:+9.3e} sd_g {r['sd_g']:.2e} sd_d {r['sd_d'][0]:.2e} mom {r['mom']:.1e} ({time.time()-t0:.0f}s)", flush=True)
