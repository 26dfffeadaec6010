import sys, time, numpy as np
from sim import Sim
import schemes as S
jit, t, steps = float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
cases = [("kernel", S.kernel, {}), ("kernel frozen", S.kernel, dict(move=False)),
         ("eps global (diag)", S.kernel_epsglobal, {}),
         ("consistent K=1", S.make_consistent(1), {}), ("consistent K=3", S.make_consistent(3), {}),
         ("consistent K=3 gas only", S.make_consistent(3, "g"), {}), ("consistent K=3 dust only", S.make_consistent(3, "d"), {})]
for P in [1]:
    for name, sch, kw in cases:
        t0 = time.time()
        s = Sim(n=12, jitter=jit, fracs=((0.5, t), (1.0, 0.05)), pressure=bool(P), **kw)
        r = s.run(sch, steps)
        print(f"{name:28s} P{P} err {r['err_end'][0]:+9.3e} {r['err_end'][1]:+9.2e} avg {r['err_avg'][0]:+9.3e} sd_g {r['sd_g']:.2e} sd_d {r['sd_d'][0]:.2e} {r['sd_d'][1]:.2e} mom {r['mom']:.1e} ({time.time()-t0:.0f}s)", flush=True)
