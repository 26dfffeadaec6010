import sys, time, numpy as np
from sim import Sim
import schemes as S
t = float(sys.argv[1]); jit = float(sys.argv[2])
for name, sch in [("split dust global", S.make_split("global", "dust")), ("split dust smooth1", S.make_split("s1", "dust")),
                  ("split dust smooth2", S.make_split("s2", "dust")), ("split gas global", S.make_split("global", "gas")),
                  ("split gas smooth1", S.make_split("s1", "gas"))]:
    t0 = time.time()
    s = Sim(n=12, jitter=jit, fracs=((0.5, t), (1.0, 0.05)))
    r = s.run(sch, 60)
    print(f"{name:22s} t {t:.0e} jit {jit} err {r['err_end'][0]:+9.3e} {r['err_end'][1]:+9.2e} avg {r['err_avg'][0]:+9.3e} sd_g {r['sd_g']:.2e} sd_d {r['sd_d'][0]:.2e} {r['sd_d'][1]:.2e} mom {r['mom']:.1e} ({time.time()-t0:.0f}s)", flush=True)
