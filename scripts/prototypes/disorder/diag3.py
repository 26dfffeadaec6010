"""is the bias a start-up transient frozen in? ramp the external acceleration"""
import sys, time, numpy as np
from sim import Sim
import schemes as S
for ramp, steps, P in [(0, 100, 1), (0.5, 100, 1), (0, 100, 0), (0.5, 100, 0)]:
    t0 = time.time()
    s = Sim(n=12, jitter=0.2, fracs=((0.5, 1e-4), (1.0, 0.05)), pressure=bool(P))
    errs = []
    for k in range(steps):
        f = min(1.0, (s.t + s.tau) / ramp) if ramp > 0 else 1.0
        s.aext[0] = 10.0 * f
        s.step(S.kernel)
        if k % 10 == 9:
            errs.append(s.drift()[0])
    print(f"ramp {ramp} P{P} err(t) every 0.1:", " ".join(f"{e:+.3f}" for e in errs), f"({time.time()-t0:.0f}s)", flush=True)
