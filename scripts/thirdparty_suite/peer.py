"""FElupe's side of scripts/peer-indent: the same flat-punch indentation as softcap's
`peer_indent` example, on the same linear-tet mesh (template/volume.msh of a suite case), with the
same material (the stable neo-Hookean energy of Smith et al. 2018 that softcap uses,
Ψ = μ/2 (I_C − 3) − μ (J − 1) + λ/2 (J − 1)², λ = λ_Lamé + μ) written for FElupe's automatic
differentiation, and the same boundary conditions and load steps.

python -m thirdparty_suite.peer volume.msh mu_pa lambda_lame_pa cx cy radius depth steps out.csv
"""
import json
import sys
import time

import numpy as np
import scipy.sparse.linalg as spla
import felupe as fem

from .physics import dense


def stable_neo_hooke(C, mu, lmbda):
    import tensortrax.math as tm

    J = tm.sqrt(tm.linalg.det(C))
    return mu / 2 * (tm.trace(C) - 3) - mu * (J - 1) + lmbda / 2 * (J - 1) ** 2


def read_msh(path):
    """Nodes and tets of a Gmsh 4.1 ASCII file with one node block and one tet block."""
    lines = open(path).read().split("\n")
    i = lines.index("$Nodes")
    n = int(lines[i + 1].split()[1])
    pts = np.array([[float(v) for v in l.split()] for l in lines[i + 3 + n: i + 3 + 2 * n]])
    j = lines.index("$Elements")
    m = int(lines[j + 1].split()[1])
    tets = np.array([[int(v) - 1 for v in l.split()[1:]] for l in lines[j + 3: j + 3 + m]])
    return pts, tets


def main(argv):
    path, mu, lame, cx, cy, radius, depth, steps, out = argv
    mu, lame, cx, cy, radius, depth = (float(v) for v in (mu, lame, cx, cy, radius, depth))
    steps = int(steps)
    t0 = time.perf_counter()
    pts, tets = read_msh(path)
    pts = pts * 1e-3
    mesh = fem.Mesh(pts, tets, "tetra")
    region = fem.RegionTetra(mesh)
    field = fem.FieldContainer([fem.Field(region, dim=3)])
    umat = fem.Hyperelastic(stable_neo_hooke, mu=mu, lmbda=lame + mu)
    body = fem.SolidBody(umat, field)
    top = pts[:, 2].max()
    base = np.where(np.abs(pts[:, 2]) < 1e-12)[0]
    punch = np.where((np.abs(pts[:, 2] - top) < 1e-12)
                     & (np.hypot(pts[:, 0] - cx * 1e-3, pts[:, 1] - cy * 1e-3) <= radius * 1e-3))[0]
    fixed = np.concatenate([3 * base, 3 * base + 1, 3 * base + 2, 3 * punch + 2])
    free = np.setdiff1d(np.arange(3 * len(pts)), fixed)
    setup_s = time.perf_counter() - t0
    u = field[0].values.reshape(-1)
    t1 = time.perf_counter()
    iterations = 0
    for s in range(1, steps + 1):
        u[3 * punch + 2] = -depth * 1e-3 * s / steps
        for it in range(50):
            r = dense(body.assemble.vector(field))
            K = body.assemble.matrix(field).tocsr()
            rf = r[free]
            if it > 0 and np.linalg.norm(rf) <= 1e-9 * max(np.linalg.norm(r), 1e-300):
                break
            du = spla.spsolve(K[free][:, free].tocsc(), -rf)
            u[free] += du
            iterations += 1
            if np.abs(du).max() <= 1e-10 * np.linalg.norm(pts.max(0) - pts.min(0)):
                break
    solve_s = time.perf_counter() - t1
    r = dense(body.assemble.vector(field))
    force = float(r[3 * punch + 2].sum())
    with open(out, "w") as f:
        f.write("node,ux,uy,uz\n")
        for i, d in enumerate(field[0].values * 1e3):
            f.write(f"{i},{d[0]:.9e},{d[1]:.9e},{d[2]:.9e}\n")
    print(json.dumps({"force_z_n": force, "punch_nodes": int(len(punch)), "setup_s": round(setup_s, 4),
                      "solve_s": round(solve_s, 4), "iterations": iterations}))


if __name__ == "__main__":
    main(sys.argv[1:])
