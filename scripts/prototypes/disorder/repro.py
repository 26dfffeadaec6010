"""Table 1: bias of the current kernel scheme. usage: python repro.py N STEPS [pressure0/1]"""
import sys, time, numpy as np
from sim import Sim
import schemes as S
n = int(sys.argv[1]); steps = int(sys.argv[2]); P = len(sys.argv) < 4 or sys.argv[3] == "1"
scheme = getattr(S, sys.argv[4]) if len(sys.argv) > 4 else S.kernel
for jit in [0.0, 0.05, 0.2]:
    for t in [1e-6, 1e-4, 1e-2]:
        t0 = time.time()
        s = Sim(n=n, jitter=jit, fracs=((0.5, t), (1.0, 0.05)), pressure=P)
        r = s.run(scheme, steps)
        print(f"jit {jit:4} t {t:7.0e} P {int(P)} err_end {r['err_end'][0]:+10.3e} {r['err_end'][1]:+9.2e}  avg {r['err_avg'][0]:+10.3e} {r['err_avg'][1]:+9.2e}"
              f"  sd_g {r['sd_g']:.2e} sd_d {r['sd_d'][0]:.2e} {r['sd_d'][1]:.2e} mom {r['mom']:.1e} ({time.time()-t0:.0f}s)", flush=True)
