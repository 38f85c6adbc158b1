"""How far each effect case is from its paired control, from the two sessions' truth/ alone:
RMS over frames and object markers of the difference of marker displacements from frame 0
(mm), its largest value, the RMS difference of the axial probe force in % of the case's largest
force, and the same after the best common scale s (f_case ≈ s f_pair, least squares): what a
refitted material stiffness cannot take up. "Beyond the contact cells": the marker RMS without the
frames × markers where either session's disk touches and the marker is within its radius of the
shaft's line (the patch: hidden markers, the contact law's own error).

For a tilted probe a second table checks the contact of each session of the pair: the object
markers inside the rigid disk (within its radius of the shaft's axis and more than 0.1 mm inside
the solid — behind its face and inside its side wall — the distance to its nearest boundary, as
`probing.disk_intrusion` measures the sampled surface; a rigid flat punch admits none), their deepest
intrusion, and the share of the
case − pair sum of squares on the frames and markers where the pair's markers intrude; and the
force on the object across the shaft (what a shaft-axis sensor does not measure), RMS over the
contact frames and its mean x, y, z in N.

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


def contact(case_dir):
    """Per frame and object marker: how far the marker is behind the disk's face (mm; > 0 inside
    the punch when within its radius of the axis) and its distance from the axis; the force on
    the object across the shaft (N, per frame); the disk radius; the contact frames."""
    pos, _ = load(case_dir)
    pr = np.genfromtxt(os.path.join(case_dir, "truth/probe.csv"), delimiter=",", names=True)
    f = np.stack([pr["fx"], pr["fy"], pr["fz"]], axis=1)
    tip = np.stack([pr["tip_x"], pr["tip_y"], pr["tip_z"]], axis=1)
    radius = None
    with open(os.path.join(case_dir, "rig/probe.toml")) as fh:
        for line in fh:
            if line.split("=")[0].strip() == "radius":
                radius = float(line.split("=")[1])
    m = np.genfromtxt(os.path.join(case_dir, "truth/markers.csv"), delimiter=",", names=True, dtype=None, encoding=None)
    s0 = np.array([(r["x"], r["y"], r["z"]) for r in m if r["frame"] == 0 and r["id"] == "shaft0"][0])
    axis = tip[0] - s0
    axis /= np.linalg.norm(axis)
    d = pos[: len(tip)] - tip[:, None, :]
    along = d @ axis
    lateral = np.linalg.norm(d - along[..., None] * axis, axis=2)
    across = f - np.outer(f @ axis, axis)
    return -along, lateral, across, radius, np.linalg.norm(f, axis=1) > 0, axis


def contact_cells(root, sessions, n):
    """(frame, marker) cells of the first n frames where, in any of `sessions`, the probe touches
    and the marker lies within the disk's radius of the shaft's line: the contact patch, where the
    truth is the contact law's and the markers are hidden under the disk."""
    cells = np.zeros((n, 0), dtype=bool)
    for c in sessions:
        _, lateral, _, radius, touching, _ = contact(os.path.join(root, c))
        under = touching[:n, None] & (lateral[:n] <= radius)
        cells = under if cells.shape[1] == 0 else cells | under
    return cells


def effect_and_pair(root):
    import tomllib
    with open(os.path.join(root, "suite.toml"), "rb") as fh:
        suite = tomllib.load(fh)
    return [(c, v["effect"], v["pair"]) for c, v in suite.items() if v["pair"]]


def main(argv):
    root = argv[0] if argv else "fixtures/thirdparty"
    print("| case | paired control | marker displacement difference RMS / max (mm) | RMS beyond the contact cells (mm) "
          "| axial force difference RMS (% of max) | beyond one scale (% of max) |")
    print("|---|---|---|---|---|---|")
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
        beyond = ~contact_cells(root, (case, pair), n)
        print(f"| {case} | {pair} | {np.sqrt((d ** 2).mean()):.3f} / {d.max():.3f} | {np.sqrt((d[beyond] ** 2).mean()):.3f} | "
              f"{100 * np.sqrt((df ** 2).mean()) / top:.1f} | {100 * np.sqrt((ds ** 2).mean()) / top:.1f} |")
    print()
    print("| tilted probe: session | markers inside the disk (frame × marker) | deepest (mm) | share of case − pair "
          "sum of squares where the pair's intrude | force across the shaft RMS (N) | its mean x, y, z (N) |")
    print("|---|---|---|---|---|---|")
    for case, effect, pair in rows:
        if not all(os.path.isdir(os.path.join(root, c)) for c in (case, pair)):
            continue
        a, _ = load(os.path.join(root, case))
        b, _ = load(os.path.join(root, pair))
        n = min(len(a), len(b))
        d2 = (np.linalg.norm((a[:n] - a[0]) - (b[:n] - b[0]), axis=2) ** 2)
        inside = {}
        for c in (case, pair):
            depth, lateral, across, radius, touching, axis = contact(os.path.join(root, c))
            if radius is None or abs(axis[2] + 1.0) < 1e-6:
                break
            intrusion = np.minimum(depth[:n], radius - lateral[:n])
            inside[c] = touching[:n, None] & (intrusion > 0.1)
            share = 100 * d2[inside[c]].sum() / d2.sum() if c == pair else None
            rms = np.sqrt((np.linalg.norm(across[touching], axis=1) ** 2).mean())
            mean = across[touching].mean(axis=0)
            print(f"| {c} | {int(inside[c].sum())} | {intrusion[inside[c]].max() if inside[c].any() else 0:.2f} | "
                  f"{'' if share is None else f'{share:.0f} %'} | {rms:.3f} | {mean[0]:+.3f}, {mean[1]:+.3f}, {mean[2]:+.3f} |")


if __name__ == "__main__":
    main(sys.argv[1:])
