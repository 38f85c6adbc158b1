"""libigl ARAP and biharmonic peers of the ICT-FaceKit reshape comparison (see ict-reshape-peers).

For each identity: the region of the neutral face deformed with the 40 landmark vertices moved to
their identity positions (igl.arap_precomputation / arap_solve, Sorkine and Alexa 2007, 50
iterations from the biharmonic solution; igl.harmonic with k = 2 on the displacements), and the
per-vertex error at every other region vertex against the identity's vertex.
"""

import json
import sys
import time
from pathlib import Path

import igl
import numpy as np


def read_obj_vertices(path):
    return np.array(
        [[float(x) for x in line.split()[1:4]] for line in open(path) if line.startswith("v ")]
    ) * 0.01  # cm -> m


def stats(x, truth, keep):
    e = np.linalg.norm(x[keep] - truth[keep], axis=1) * 1e3
    e.sort()
    return e.mean(), e[int(round(0.95 * (len(e) - 1)))], e[-1]


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: ict-reshape-peers ICT_DIR OUT_DIR")
    ict, out = Path(sys.argv[1]), Path(sys.argv[2])
    region = json.loads((out / "region.json").read_text())
    index = np.array(region["ict_vertex"], dtype=np.int64)
    faces = np.array(region["triangles"], dtype=np.int64)
    b = np.array(region["landmarks"], dtype=np.int64)
    keep = np.setdiff1d(np.arange(len(index)), b)
    v = read_obj_vertices(ict / "neutral.obj")[index]
    rows = []
    for i in range(5):
        truth = read_obj_vertices(ict / "identities" / f"identity{i:03d}.obj")[index]
        t0 = time.perf_counter()
        d = igl.harmonic(v, faces, b, truth[b] - v[b], 2)
        bih = v + d
        t_bih = time.perf_counter() - t0
        t0 = time.perf_counter()
        data = igl.ARAPData()
        data.max_iter = 50
        igl.arap_precomputation(v, faces, 3, b.astype(np.int32), data)
        arap = igl.arap_solve(truth[b], data, bih)
        t_arap = time.perf_counter() - t0
        for name, x, t in [("libigl biharmonic", bih, t_bih), ("libigl ARAP", arap, t_arap)]:
            m, p, mx = stats(x, truth, keep)
            rows.append((i, name, m, p, mx, t))
            print(f"| {i:03d} | {name} | {m:.3f} | {p:.3f} | {mx:.3f} |  | {t:.2f} |")
    with open(out / "igl_peers.csv", "w") as f:
        f.write("identity,method,mean_mm,p95_mm,max_mm,seconds\n")
        for r in rows:
            f.write("%03d,%s,%.4f,%.4f,%.4f,%.3f\n" % r)


if __name__ == "__main__":
    main()
