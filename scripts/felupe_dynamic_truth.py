#!/usr/bin/env python3
"""A dynamic truth computed by a third-party FE code (FElupe), for `softcap synth` to render:
the clamped bar of fixtures/scenarios/dynamic/bar-release.toml released from a push, solved
with FElupe's quadratic (20-node serendipity) hexahedra and its nearly-incompressible Neo-Hooke
material, mass and time stepping written here (consistent mass, Rayleigh damping
C = alpha M + beta K(u_n), Newmark average acceleration, Newton on the full tangent). Nothing of
softcap's FEM is used: different element order, element type, material law and damping matrix.

    scripts/felupe-dynamic-truth fixtures/dynamic/felupe-bar-corot  # installs its own venv
    scripts/felupe-dynamic-truth fixtures/dynamic/felupe-bar --damping k0   # the K0-damped truth

Damping: K(u_n) is FElupe's tangent at the start of each time step, so the stiffness-proportional
force rotates with the body (a rigid rotation of the sagged bar is not read as strain rate);
`--damping k0` uses the tangent of the straight, unloaded bar instead, which is not rotation
invariant: the sagged bar's vertical bending then rings down with a damping ratio of about 0.86
against 0.049 laterally.

Writes OUT/truth.toml and OUT/positions.csv (the format softcap_synth::dynamic::external reads:
every corner node of the structured grid, numbered i + (nx+1)(j + (ny+1)k), per frame, mm).
"""
import sys
import time

import numpy as np
import scipy
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import felupe as fem

# the object of fixtures/scenarios/dynamic/bar-release.toml (SI)
L, W, H = 0.200, 0.030, 0.030
CELLS = (16, 3, 3)
E, NU, RHO = 1.0e6, 0.45, 1100.0
ALPHA, BETA = 0.8, 1.0e-3
GRAVITY = np.array([0.0, 0.0, -9.81])
FPS, FRAMES, SUBSTEPS = 30.0, 60, 8
# the hand: smoothstep ramp of the total force over PUSH_FRAMES from t_a, let go at t_b
REST_FRAMES, PUSH_FRAMES = 2, 8
PUSH_FORCE = np.array([0.0, 0.5, -0.9])
PUSH_AT = np.array([L - 0.020, 0.0, H / 2])
PUSH_RADIUS = 0.020


def smoothstep(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def consistent_mass(region, cells, npoints):
    """M_ab = rho sum_q h_a(q) h_b(q) dV(q) per cell, assembled; scalar (per point)."""
    h = np.asarray(region.h)  # (basis, quadrature point) or (basis, qp, cells)
    dv = np.asarray(region.dV)  # (qp, cells)
    if h.ndim == 2:
        h = h[:, :, None]
    nb = cells.shape[1]
    vals = RHO * np.einsum("aqc,bqc,qc->abc", np.broadcast_to(h, (nb, dv.shape[0], dv.shape[1])),
                           np.broadcast_to(h, (nb, dv.shape[0], dv.shape[1])), dv)
    rows = np.repeat(cells[:, :, None], nb, axis=2).transpose(1, 2, 0)
    cols = np.repeat(cells[:, None, :], nb, axis=1).transpose(1, 2, 0)
    return sp.coo_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(npoints, npoints)).tocsr()


def main():
    args = sys.argv[1:]
    damping = "current"
    if "--damping" in args:
        i = args.index("--damping")
        damping = args[i + 1] if i + 1 < len(args) else ""
        del args[i:i + 2]
    if damping not in ("current", "k0") or len(args) != 1:
        sys.exit("usage: felupe_dynamic_truth.py OUT [--damping current|k0]")
    out = args[0]
    t_start = time.time()
    nx, ny, nz = CELLS
    mesh = fem.Cube(a=(0.0, -W / 2, -H / 2), b=(L, W / 2, H / 2), n=(nx + 1, ny + 1, nz + 1))
    corners = mesh.points.copy()
    quad = mesh.add_midpoints_edges()
    region = fem.RegionQuadraticHexahedron(quad)
    field = fem.FieldContainer([fem.Field(region, dim=3)])
    mu, bulk = E / (2 * (1 + NU)), E / (3 * (1 - 2 * NU))
    solid = fem.SolidBody(fem.NeoHooke(mu=mu, bulk=bulk), field)
    npts = quad.npoints
    ndof = 3 * npts
    ms = consistent_mass(region, np.asarray(region.mesh.cells), npts)
    assert abs(ms.sum() - RHO * L * W * H) < 1e-9 * RHO * L * W * H, "consistent mass != rho V"
    M = sp.kron(ms, sp.identity(3), format="csr")
    g = M @ np.tile(GRAVITY, npts)
    clamp = fem.Boundary(field[0], fx=0.0)
    dof0, dof1 = fem.dof.partition(field, {"clamp": clamp})
    # the hand's nodes (every node of the mesh within the radius, on the boundary)
    pts = quad.points
    near = np.linalg.norm(pts - PUSH_AT, axis=1) <= PUSH_RADIUS
    on_top = np.abs(pts[:, 2] - H / 2) < 1e-9
    hand = np.where(near & on_top)[0]
    t_a = (REST_FRAMES - 0.5) / FPS
    t_b = t_a + PUSH_FRAMES / FPS

    def hand_force(t):
        f = np.zeros(ndof)
        if t < t_b and len(hand):
            total = PUSH_FORCE * smoothstep((t - t_a) / (t_b - t_a))
            for n in hand:
                f[3 * n:3 * n + 3] += total / len(hand)
        return f

    def internal(u):
        field[0].values[:] = u.reshape(-1, 3)
        return np.asarray(solid.assemble.vector(field).todense()).ravel()

    def tangent(u):
        field[0].values[:] = u.reshape(-1, 3)
        return solid.assemble.matrix(field).tocsr()

    def solve_free(A, r):
        x = np.zeros(ndof)
        x[dof1] = spla.spsolve(A[dof1][:, dof1].tocsc(), r[dof1])
        return x

    # frame 0: static sag under gravity (load ramp, Newton)
    u = np.zeros(ndof)
    for lam in np.linspace(0.2, 1.0, 5):
        for _ in range(30):
            r = lam * g - internal(u)
            if np.linalg.norm(r[dof1]) < 1e-10 * np.linalg.norm(g):
                break
            u += solve_free(tangent(u), r)
    K0 = tangent(np.zeros(ndof))
    C = ALPHA * M + BETA * K0
    damping_text = "Rayleigh C = alpha M + beta K0 (tangent of the unloaded bar)"
    if damping == "current":
        damping_text = "Rayleigh C = alpha M + beta K(u_n) (tangent at the start of each step: rotates with the body)"
    v = np.zeros(ndof)
    a = np.zeros(ndof)
    h = 1.0 / (FPS * SUBSTEPS)
    frames = [u.copy()]
    t = 0.0
    newton_max = 0
    for frame in range(1, FRAMES):
        for _ in range(SUBSTEPS):
            t += h
            if damping == "current":
                C = ALPHA * M + BETA * tangent(u)
            f_ext = g + hand_force(t)
            u_pred = u + h * v + 0.25 * h * h * a
            un = u_pred.copy()
            for it in range(25):
                an = 4.0 / (h * h) * (un - u - h * v) - a
                vn = v + 0.5 * h * (a + an)
                r = f_ext - internal(un) - C @ vn - M @ an
                if np.linalg.norm(r[dof1]) < 1e-9 * max(np.linalg.norm(f_ext), 1e-12):
                    break
                A = tangent(un) + (2.0 / h) * C + (4.0 / (h * h)) * M
                un += solve_free(A, r)
            newton_max = max(newton_max, it)
            an = 4.0 / (h * h) * (un - u - h * v) - a
            v = v + 0.5 * h * (a + an)
            a, u = an, un
        frames.append(u.copy())
        print(f"frame {frame}/{FRAMES - 1}", file=sys.stderr)

    # corner nodes in the structured numbering of softcap_mesh::box_tet_mesh
    step = np.array([L / nx, W / ny, H / nz])
    ijk = np.rint((corners - np.array([0.0, -W / 2, -H / 2])) / step).astype(int)
    index = ijk[:, 0] + (nx + 1) * (ijk[:, 1] + (ny + 1) * ijk[:, 2])
    assert sorted(index) == list(range(len(corners)))
    order = np.argsort(index)
    with open(f"{out}/positions.csv", "w") as fh:
        fh.write("frame,t_s,node,x,y,z\n")
        for k, uk in enumerate(frames):
            x = (pts[: len(corners)] + uk.reshape(-1, 3)[: len(corners)])[order] * 1e3
            tk = k / FPS
            for n, p in enumerate(x):
                fh.write(f"{k},{tk:.6f},{n},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}\n")
    with open(f"{out}/truth.toml", "w") as fh:
        fh.write("# written by scripts/felupe_dynamic_truth.py; do not edit\n")
        fh.write(
            f'solver = "FElupe {fem.__version__} (numpy {np.__version__}, scipy {scipy.__version__}): '
            f'{CELLS[0]}x{CELLS[1]}x{CELLS[2]} quadratic serendipity hexahedra (20 nodes), nearly-incompressible '
            f'Neo-Hooke mu = {mu:.6g} Pa, bulk = {bulk:.6g} Pa, consistent mass, {damping_text}, '
            f'Newmark average acceleration, {SUBSTEPS} steps per frame, Newton (at most {newton_max + 1} iterations)"\n'
        )
        fh.write(f"cells = [{nx}, {ny}, {nz}]\n")
        fh.write(f"min_mm = [0.0, {-W / 2 * 1e3}, {-H / 2 * 1e3}]\nmax_mm = [{L * 1e3}, {W / 2 * 1e3}, {H / 2 * 1e3}]\n")
        fh.write(f"young_pa = {E}\npoisson = {NU}\ndensity_kg_m3 = {RHO}\n")
        fh.write(f"rayleigh_alpha_per_s = {ALPHA}\nrayleigh_beta_s = {BETA}\n")
        fh.write(f"gravity_m_s2 = [{GRAVITY[0]}, {GRAVITY[1]}, {GRAVITY[2]}]\nclamped_at_x_min = true\n")
        fh.write(f"interactions = [[{t_a:.6f}, {t_b:.6f}]]\n")
        fh.write(
            f'motion = "release: clamped at x = 0, sagging under gravity in frame 0 (FElupe static solve); a hand pushes '
            f'{PUSH_FORCE.tolist()} N in total on the {len(hand)} top-face nodes within {PUSH_RADIUS * 1e3:.0f} mm of '
            f'{(PUSH_AT * 1e3).tolist()} mm (smoothstep over {PUSH_FRAMES} frames) and lets go at t = {t_b:.4f} s"\n'
        )
    print(f"wrote {out}: {len(frames)} frames in {time.time() - t_start:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
