"""python -m thirdparty_suite --out DIR [--case NAME ...] [--list]

Generates the third-party truth suite (see scripts/thirdparty-suite)."""
import argparse
import os
import sys
import time

import numpy as np

from . import cases as suite
from .geometry import locate, mesh_object, quadratic_cells
from .probing import PROTOCOLS, replan, simulate, uniform_steps
from .session import write_session


def markers_for(case):
    """Marker grid on the top face (the same layout for every case of one geometry)."""
    rng = np.random.default_rng(7)
    g, mk = case["geometry"], case["markers"]
    h = g["size_mm"][-1]
    if g["shape"] == "block":
        lx, ly = g["size_mm"][:2]
        xs = np.linspace(mk["margin_mm"], lx - mk["margin_mm"], mk["grid"])
        ys = np.linspace(mk["margin_mm"], ly - mk["margin_mm"], mk["grid"])
        pts = [(x, y) for y in ys for x in xs]
    else:
        r = g["size_mm"][0]
        xs = np.linspace(mk["margin_mm"], 2 * r - mk["margin_mm"], mk["grid"])
        pts = [(x, y) for y in xs for x in xs if np.hypot(x - r, y - r) <= r - mk["margin_mm"]]
    pts = np.array(pts) + rng.uniform(-mk["jitter_mm"], mk["jitter_mm"], (len(pts), 2))
    return np.hstack([pts, np.full((len(pts), 1), h)])


def main(argv=None):
    ap = argparse.ArgumentParser(prog="thirdparty-suite")
    ap.add_argument("--out", required=False, default="fixtures/thirdparty")
    ap.add_argument("--case", action="append", default=[])
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--locations", type=int, default=None, help="only the first N probe locations (a quick look)")
    ap.add_argument("--protocol", choices=PROTOCOLS, default="standard",
                    help="re-record every chosen case under this protocol of the diagnosis's planner "
                         "(case names get the suffix -PROTOCOL; standard: the cases as they are)")
    a = ap.parse_args(argv)
    all_cases = [replan(c, a.protocol) for c in suite.cases()]
    if a.list:
        for c in all_cases:
            print(f"{c['name']:22s} effect={c['effect'] or 'none':16s} pair={c['pair'] or '-'}")
        return 0
    if a.protocol != "standard":
        a.case = [f"{n}-{a.protocol}" for n in a.case]
    names = {c["name"] for c in all_cases}
    for n in a.case:
        if n not in names:
            print(f"thirdparty-suite: unknown case '{n}' (see --list)", file=sys.stderr)
            return 2
    chosen = [c for c in all_cases if not a.case or c["name"] in a.case]
    if a.locations:
        for c in chosen:
            c["locations_mm"] = c["locations_mm"][: a.locations]
            c["depths_mm"] = c["depths_mm"][: a.locations]
    for c in chosen:
        if (c["material"]["kind"] == "viscoelastic" and not uniform_steps(c)
                and c["protocol"].get("control") == "force"):
            print(f"thirdparty-suite: {c['name']}: a force-controlled viscoelastic material is integrated with "
                  "one time step; "
                  f"--protocol {a.protocol} changes the frame steps", file=sys.stderr)
            return 2
    import felupe
    import gmsh
    versions = {"felupe": felupe.__version__, "gmsh": gmsh.__version__}
    os.makedirs(a.out, exist_ok=True)
    meshes, sims = {}, {}
    for c in chosen:
        t0 = time.time()
        print(f"{c['name']}: meshing", file=sys.stderr)
        gkey = repr((c["geometry"], c.get("inclusion")))
        if gkey not in meshes:
            g = c["geometry"]
            pts, tets, tags = mesh_object(g["shape"], g["size_mm"], g["h_top_mm"], g["h_bottom_mm"], c.get("inclusion"))
            p10, c10 = quadratic_cells(pts, tets)
            meshes[gkey] = (pts, tets, tags, p10, c10)
        pts, tets, tags, p10, c10 = meshes[gkey]
        mk = markers_for(c)
        mcells, mlams = locate(pts, tets, mk)
        pkey = suite.physics_key(c)
        if pkey not in sims:
            print(f"{c['name']}: solving {len(tets)} tets ({len(p10)} nodes)", file=sys.stderr)
            sims[pkey] = simulate(c, (p10, c10, tags), mcells, mlams, log=lambda s: print(s, file=sys.stderr))
        sim = sims[pkey]
        frame0 = pts + sim["rest_u"][: len(pts)]
        ids = [f"m{k:02d}" for k in range(len(mk))]
        write_session(os.path.join(a.out, c["name"]), c, sim, (frame0, tets), ids, versions)
        print(f"{c['name']}: written in {time.time() - t0:.1f} s", file=sys.stderr)
    with open(os.path.join(a.out, "suite.toml"), "w") as f:
        f.write("# case → effect and paired control (written by scripts/thirdparty-suite)\n")
        for c in all_cases:
            f.write(f'[{c["name"]}]\neffect = "{c["effect"] or "none"}"\npair = "{c["pair"] or ""}"\n')
    return 0


if __name__ == "__main__":
    sys.exit(main())
