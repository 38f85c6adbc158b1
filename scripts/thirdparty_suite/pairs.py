"""How far each effect case is from its paired control, from the two sessions' truth/ alone:
RMS over frames and object markers of the difference of marker displacements from frame 0
(mm), its largest value, the RMS difference of the axial probe force in % of the case's largest
force, and the same after the best common scale s (f_case ≈ s f_pair, least squares): what a
refitted material stiffness cannot take up.

python -m thirdparty_suite.pairs [fixtures/thirdparty [CASE OTHER]]   (CASE OTHER: any two cases, e.g. a
control against clean)
"""
import os
import sys

import numpy as np


def load(case_dir):
    m = np.genfromtxt(os.path.join(case_dir, "truth/markers.csv"), delimiter=",", names=True, dtype=None, encoding=None)
    ids = sorted({i for i in m["id"] if not i.startswith("shaft")})
    nf = int(m["frame"].max()) + 1
    pos = np.zeros((nf, len(ids), 3))
    shaft = np.zeros((nf, 2, 3))
    index = {k: j for j, k in enumerate(ids)}
    for r in m:
        p = (r["x"], r["y"], r["z"])
        if r["id"].startswith("shaft"):
            shaft[r["frame"], int(r["id"][5:])] = p
        else:
            pos[r["frame"], index[r["id"]]] = p
    pr = np.genfromtxt(os.path.join(case_dir, "truth/probe.csv"), delimiter=",", names=True)
    f = np.stack([pr["fx"], pr["fy"], pr["fz"]], axis=1)
    axis = shaft[:, 0] - shaft[:, 1]
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return pos, np.einsum("ij,ij->i", f, axis)


def effect_and_pair(root):
    import tomllib
    with open(os.path.join(root, "suite.toml"), "rb") as fh:
        suite = tomllib.load(fh)
    return [(c, v["effect"], v["pair"]) for c, v in suite.items() if v["pair"]]


def main(argv):
    root = argv[0] if argv else "fixtures/thirdparty"
    print("| case | paired control | marker displacement difference RMS / max (mm) | axial force difference RMS (% of max) "
          "| beyond one scale (% of max) |")
    print("|---|---|---|---|---|")
    rows = [(argv[1], None, argv[2])] if len(argv) >= 3 else effect_and_pair(root)
    for case, effect, pair in rows:
        if not all(os.path.isdir(os.path.join(root, c)) for c in (case, pair)):
            continue
        a, fa = load(os.path.join(root, case))
        b, fb = load(os.path.join(root, pair))
        n = min(len(a), len(b))
        da = (a[:n] - a[0]) - (b[:n] - b[0])
        d = np.linalg.norm(da, axis=2)
        df = fa[:n] - fb[:n]
        s = float(fa[:n] @ fb[:n]) / max(float(fb[:n] @ fb[:n]), 1e-300)
        ds = fa[:n] - s * fb[:n]
        top = np.abs(fa).max()
        print(f"| {case} | {pair} | {np.sqrt((d ** 2).mean()):.3f} / {d.max():.3f} | "
              f"{100 * np.sqrt((df ** 2).mean()) / top:.1f} | {100 * np.sqrt((ds ** 2).mean()) / top:.1f} |")


if __name__ == "__main__":
    main(sys.argv[1:])
