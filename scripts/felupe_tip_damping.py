#!/usr/bin/env python3
"""Tip damping of a FElupe dynamic truth (fixtures/dynamic/*/positions.csv): a damped sinusoid
fitted to the mean y and z of the tip nodes (x = 200 mm) after the release (t > T_RELEASE s);
prints frequency and damping ratio per direction. Numbers of fixtures/dynamic/felupe-bar-corot/README.md:

    .venv-felupe/bin/python scripts/felupe_tip_damping.py fixtures/dynamic/felupe-bar-corot [T_RELEASE]
"""
import sys, numpy as np
from scipy.optimize import curve_fit
d = np.loadtxt(sys.argv[1] + "/positions.csv", delimiter=",", skiprows=1)
t_release = float(sys.argv[2]) if len(sys.argv) > 2 else 0.3167
frames = np.unique(d[:, 0]).astype(int)
x0 = d[d[:, 0] == 0]
tip = x0[:, 3] > 199.9
ids = x0[tip, 2].astype(int)
T, Y, Z = [], [], []
for f in frames:
    r = d[d[:, 0] == f]
    T.append(r[0, 1]); Y.append(r[ids, 4].mean()); Z.append(r[ids, 5].mean())
T, Y, Z = map(np.array, (T, Y, Z))
m = T > t_release
def model(t, a, b, s, w, c):
    return np.exp(-s * t) * (a * np.cos(w * t) + b * np.sin(w * t)) + c
for name, q in (("y", Y), ("z", Z)):
    t = T[m] - T[m][0]; v = q[m]
    best = None
    for w0 in np.linspace(15, 30, 16):
        for s0 in (0.5, 2, 8, 20):
            try:
                p, _ = curve_fit(model, t, v, p0=[v[0] - v[-1], 0, s0, w0, v[-1]], bounds=([-1e3, -1e3, 0, 10, -1e3], [1e3, 1e3, 50, 40, 1e3]), maxfev=20000)
            except Exception:
                continue
            rss = ((model(t, *p) - v) ** 2).sum()
            if best is None or rss < best[0]:
                best = (rss, p)
    rss, p = best
    s, w = abs(p[2]), abs(p[3])
    wn = np.hypot(s, w)
    print(f"tip {name}: f_d {w/2/np.pi:.3f} Hz, f_n {wn/2/np.pi:.3f} Hz, zeta {s/wn:.4f}, amplitude {np.hypot(p[0],p[1]):.2f} mm, rms fit {np.sqrt(rss/len(t)):.3f} mm, frame0 {q[0]:.2f}, last {q[-1]:.2f}")
