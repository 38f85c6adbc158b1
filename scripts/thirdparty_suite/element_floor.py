"""python -m thirdparty_suite.element_floor CASE [tetra4|tetra4-refined|tetra10 ...]

How much of a case's truth the element order alone changes: the case re-solved by the suite's
own FElupe code (same material, mesh, punch, protocol) with linear tets on the case's linear mesh
(`tetra4`), with linear tets on that mesh split 1 → 8 through its edge midpoints (`tetra4-refined`:
the nodes of the quadratic mesh; softcap's `refine_tets` mesh), or as the truth itself (`tetra10`),
and compared with the committed truth's markers (`fixtures/thirdparty/CASE/truth/markers.csv`):
RMS per cell (contact frames near the tip / away from it / released frames near a touched
location / the rest), as softcap's `plasticity_floor` example prints them."""
import sys
import time
from pathlib import Path

import numpy as np
import felupe as fem

from . import cases as suite
from . import probing
from .__main__ import markers_for
from .geometry import locate, mesh_object, quadratic_cells
from .physics import materials

CORNER_SPLIT = [(0, 4, 6, 7), (4, 1, 5, 8), (6, 5, 2, 9), (7, 8, 9, 3),
                (4, 9, 5, 8), (4, 9, 8, 7), (4, 9, 7, 6), (4, 9, 6, 5)]


def positive(points, tets):
    """Tets reordered to positive volume."""
    a, b, c, d = (points[tets[:, i]] for i in range(4))
    neg = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    tets = tets.copy()
    tets[neg, 1], tets[neg, 2] = tets[neg, 2], tets[neg, 1].copy()
    return tets


class LinearModel(probing.Model):
    """The suite's Model on linear tets (vertical punch, bonded base only)."""

    def __init__(self, points, cells, tags, material, dtime, support, height):
        self.mesh = fem.Mesh(points, cells, "tetra")
        self.region = fem.RegionTetra(self.mesh)
        self.field = fem.FieldContainer([fem.Field(self.region, dim=3)])
        self.bodies = [fem.SolidBody(m, self.field) for m in materials(material, len(cells), tags, dtime)]
        self.points = points
        self.n = len(points)
        self.height = height
        self.support = support
        self.body_force = np.zeros(3 * self.n)
        used = np.unique(cells)
        self.base = used[points[used, 2] < 1e-6]
        self.top = used[np.abs(points[used, 2] - height) < 1e-6]
        self.top_area = np.zeros(self.n)
        self.slip = np.zeros((self.n, 2))
        self.last_pressure = np.zeros(self.n)


def run(case, variant):
    g = case["geometry"]
    pts, tets, tags = mesh_object(g["shape"], g["size_mm"], g["h_top_mm"], g["h_bottom_mm"], case.get("inclusion"))
    p10, c10 = quadratic_cells(pts, tets)
    mk = markers_for(case)
    if variant == "tetra10":
        mcells, mlams = locate(pts, tets, mk)
        return probing.simulate(case, (p10, c10, tags), mcells, mlams, log=lambda s: None)
    if variant == "tetra4":
        points, cells = pts, positive(pts, tets)
    else:
        points = p10
        cells = positive(p10, np.concatenate([c10[:, list(s)] for s in CORNER_SPLIT]))
        tags = np.concatenate([tags] * len(CORNER_SPLIT))
    mcells, mlams = locate(points, cells, mk)
    saved = (probing.Model, probing.m_pos_markers)
    probing.Model = LinearModel
    probing.m_pos_markers = lambda model, cells_, mc, ml: np.einsum(
        "ka,kad->kd", ml, (model.points + model.u)[cells_[mc]])
    try:
        return probing.simulate(case, (points, cells, tags), mcells, mlams, log=lambda s: None)
    finally:
        probing.Model, probing.m_pos_markers = saved


def truth_markers(name, nm):
    rows = np.genfromtxt(Path(__file__).resolve().parents[2] / "fixtures/thirdparty" / name / "truth/markers.csv", delimiter=",", skip_header=1,
                         dtype=None, encoding=None)
    nt = max(int(r[0]) for r in rows) + 1
    out = np.zeros((nt, nm, 3))
    for r in rows:
        if str(r[1]).startswith("m"):
            out[int(r[0]), int(str(r[1])[1:])] = (r[2], r[3], r[4])
    return out


def main(argv):
    name, variants = argv[0], argv[1:] or ["tetra4", "tetra4-refined"]
    case = next(c for c in suite.cases() if c["name"] == name)
    r_tip = case["probe"]["radius_mm"]
    for v in variants:
        t0 = time.process_time()
        sim = run(case, v)
        cpu = time.process_time() - t0
        x = sim["markers"]
        nt, nm = x.shape[:2]
        truth = truth_markers(name, nm)[:nt]
        rest = truth[0]
        contact = np.abs(sim["forces"][:, 2]) > 1e-9
        touched, acc = [], np.zeros((4, 2))
        rest_acc = np.zeros((4, 2))
        for k in range(nt):
            tip = sim["tips"][k]
            if contact[k] and all(np.linalg.norm(t[:2] - tip[:2]) > 0.1 for t in touched):
                touched.append(tip)
            for m in range(nm):
                near_now = np.linalg.norm(rest[m, :2] - tip[:2]) <= 1.5 * r_tip
                near_any = any(np.linalg.norm(rest[m, :2] - t[:2]) <= 1.5 * r_tip for t in touched)
                c = 0 if contact[k] and near_now else 1 if contact[k] else 2 if near_any else 3
                acc[c] += (np.sum((x[k, m] - truth[k, m]) ** 2), 1)
                rest_acc[c] += (np.sum((rest[m] - truth[k, m]) ** 2), 1)
        print(f"{name} {v}: {cpu:.0f} CPU-s")
        for c, label in enumerate(["contact near", "contact far", "released near", "other"]):
            print(f"  {label:>14}: model {np.sqrt(acc[c, 0] / max(acc[c, 1], 1)):.4f} mm, "
                  f"rest {np.sqrt(rest_acc[c, 0] / max(rest_acc[c, 1], 1)):.4f} mm, {int(acc[c, 1])} cells")
        sys.stdout.flush()


if __name__ == "__main__":
    main(sys.argv[1:])
