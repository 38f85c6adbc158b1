"""The probing protocol and its quasi-static solution, frame by frame.

Per location: the probe hovers above the location, ramps down to its depth, holds, ramps back up
to the surface, lifts off and moves to the next location. Frame 0 is the rest state with the probe
hovering above the first location. The punch is a rigid flat disk with a sharp edge:
- vertical shaft: an active set of top-face nodes under the disk take the punch's z displacement
  (frictionless: their x, y are free); nodes that penetrate the face are added; when the total
  force turns tensile the punch has lost contact and the set is emptied. Under force control
  the vertical punch is the tilted one's frictionless solid disk below (`Punch.walled`);
- tilted shaft (probe friction case and its pair, support-slip and its pair): the punch is a solid
  disk (its face perpendicular to the shaft, its side wall a cylinder of the disk's radius round
  the shaft) that touches the surface from the depth −R tan θ on (its low rim first; the punch
  travels there from first touch in steps, `approach`). The top face is sampled on a lattice of
  points per 6-node face (`surface_lattice`, the nodes among them); a point inside the solid is
  projected onto the face, or onto the side wall when it was beside the disk and is nearer the
  wall (`disk_projection`), and a penalty pushes it out along that normal: one-sided on the gap
  (frictionless), or, for an active set, on the full relative motion from the point where it
  touched (sticking friction). Point-to-rigid-surface penalty with the closest-point projection
  (Wriggers, Computational Contact Mechanics, 2nd ed., §4.1, §5.2). Before (a face without side
  wall, on the nodes only), material beside the low rim of the tilted disk moved into the solid
  (1.66 mm behind the face, 1.1 mm inside the rim in probe-friction-pair's first fixtures) and
  the element faces between the nodes cut through the rim.
"""
import os
import sys

import numpy as np
import scipy.sparse as sp

from .physics import Model, interpolate_markers


def protocol(case):
    """Frame list: dicts with t (s), loc (index or None), depth_mm along the shaft below the
    surface point (negative: hovering), phase name; under force control (`control` = "force",
    `peak_force_n` per location) also force_n, the axial force the probe is driven to (the
    location's peak times k/n on the ramps, the peak on the holds, None off the object), the
    depth then being only the nominal one (`simulate` solves the depth that gives the force).
    The time of a frame is the sum of the steps into it in units of the frame period 1/fps
    (exact in floating point for the standard protocol's unit steps and `ramp_step` 0.5): the
    ramp and unload frames' steps are `ramp_step` periods (`replan` "faster-ramps"), the rest frames after a release
    `rest` = [frames, seconds] ("rest-after-release")."""
    p = case["protocol"]
    dt = 1.0 / p["fps"]
    frames = []
    elapsed = [0.0]  # in frame periods

    peaks = p.get("peak_force_n") if p.get("control") == "force" else None

    def add(loc, depth, phase, step=1.0, load=None):
        if frames:
            elapsed[0] += step
        fr = {"t": elapsed[0] * dt, "loc": loc, "depth": depth, "phase": phase}
        if peaks is not None:
            # force control: the target axial force, the location's peak times the ramp's fraction
            fr["force_n"] = None if load is None else peaks[loc] * load
        frames.append(fr)

    hover = -p["hover_mm"]
    ramp_step = p.get("ramp_step", 1.0)
    add(0, hover, "rest")
    for li, dmax in enumerate(case["depths_mm"]):
        for _ in range(p["approach"]):
            add(li, hover, "approach")
        n = p["ramp"]
        for k in range(1, n + 1):
            add(li, dmax * k / n, "ramp", ramp_step, k / n)
        for _ in range(p["hold"]):
            add(li, dmax, "hold", load=1.0)
        n = p["unload"]
        for k in range(n - 1, -1, -1):
            add(li, dmax * k / n, "unload", ramp_step, k / n)
        for _ in range(p["release"]):
            add(li, hover, "release")
        if "rest" in p:
            count, seconds = p["rest"]
            for _ in range(count):
                add(li, hover, "rest-after-release", seconds / count / dt)
    return frames, dt


# The next experiments the diagnosis plans (crates/softcap_diagnose/src/protocols.rs, `Protocol`)
# as changes of the probing schedule, with the planner's meaning; "standard" is the case as it is.
PROTOCOLS = ("standard", "longer-holds", "faster-ramps", "rest-after-release", "oblique-probe")
# protocols.rs REST_AFTER_RELEASE_S, REST_FRAMES
REST_AFTER_RELEASE_S = 3.0
REST_FRAMES = 10
OBLIQUE_DEG = 20.0


def replan(case, name):
    """The case re-recorded under protocol `name` (PROTOCOLS), the case itself for "standard":
    - longer-holds: every hold three times as long (three times the hold frames, same rate);
    - faster-ramps: the loading and unloading ramps twice as fast as the case's (the same frames
      and depths, half the time step between them: the camera and DAQ sample the ramps at twice
      the rate), as the planner halves the recorded ramp steps (protocols.rs `frame_steps`);
    - rest-after-release: the object at rest REST_AFTER_RELEASE_S after each location's release,
      observed at REST_FRAMES evenly spaced frames (the probe hovering);
    - oblique-probe: the shaft tilted OBLIQUE_DEG about the axis perpendicular to it and the
      support normal (world y for a vertical shaft), the protocol's depths along the new shaft.
    The planner's fifth, near-support (locations moved towards the marker nearest the support),
    has no meaning here: every marker of the suite is on the top face, none nearer the support.
    The seed (the rig: cameras, FSR, clock, noise) stays: the same rig records again."""
    import copy

    if name not in PROTOCOLS:
        raise ValueError(f"unknown protocol '{name}' (one of {', '.join(PROTOCOLS)})")
    c = copy.deepcopy(case)
    if name == "standard":
        return c
    p = c["protocol"]
    if name == "longer-holds":
        p["hold"] *= 3
    elif name == "faster-ramps":
        p["ramp_step"] = p.get("ramp_step", 1.0) * 0.5
    elif name == "rest-after-release":
        p["rest"] = [REST_FRAMES, REST_AFTER_RELEASE_S]
    else:
        axis = np.array(c.get("probe_axis", [0.0, 0.0, -1.0]), float)
        axis /= np.linalg.norm(axis)
        about = np.cross(axis, [0.0, 0.0, 1.0])
        about = about / np.linalg.norm(about) if np.linalg.norm(about) > 1e-6 else np.array([0.0, 1.0, 0.0])
        th = np.radians(OBLIQUE_DEG)
        # Rodrigues' rotation of the shaft about `about`
        tilted = axis * np.cos(th) + np.cross(about, axis) * np.sin(th) + about * (about @ axis) * (1 - np.cos(th))
        c["probe_axis"] = [round(float(v), 4) for v in tilted]
    c["name"] = f"{case['name']}-{name}"
    c["description"] = f"{case['description']} Re-recorded under the protocol {name}."
    return c


def uniform_steps(case):
    """Whether every frame step of the case's protocol is one frame period (a force-controlled
    rate-dependent material is integrated with that one time step; under position control each
    frame takes the time it spans, `simulate`)."""
    p = case["protocol"]
    return p.get("ramp_step", 1.0) == 1.0 and "rest" not in p


class Punch:
    """Rigid flat punch acting on a Model."""

    def __init__(self, model, radius, friction):
        self.m = model
        self.R = radius
        self.friction = friction  # "none" | "stick"
        self.active = set()
        self.anchor = {}
        self.beside = None
        self.k_pen = None
        # The vertical punch as the tilted one's disk with a side wall (penalty contact on the
        # sampled surface) instead of its nodal active set: force control's F(depth) is then
        # continuous (see force_controlled).
        self.walled = False

    def step(self, tip, axis, fixed_support):
        vertical = abs(axis[2] + 1.0) < 1e-9
        if vertical and not self.walled:
            return self._vertical(tip, fixed_support)
        if self.friction == "stick":
            return self._tilted(tip, axis, fixed_support)
        return self._tilted_frictionless(tip, axis, fixed_support)

    def _candidates(self, tip, axis):
        x = m_pos(self.m)
        d = x[self.m.top] - tip
        along = d @ axis
        lateral = np.linalg.norm(d - np.outer(along, axis), axis=1)
        return self.m.top, along, lateral

    def _vertical(self, tip, fixed_support):
        m = self.m
        X = m.points
        down = np.array([0.0, 0.0, -1.0])
        r = None
        for _ in range(8):
            ids, along, lat = self._candidates(tip, down)
            pen = {int(i) for i, a, l in zip(ids, along, lat) if l <= self.R and a < 1e-9}
            if r is not None and not (pen - self.active):
                break
            self.active |= pen
            fixed = dict(fixed_support)
            for i in self.active:
                fixed[3 * i + 2] = tip[2] - X[i, 2]
            r = m.solve(fixed)
            fz = sum(r[3 * i + 2] for i in self.active)
            if self.active and fz > 0.0:
                # tensile total force: the punch has left the surface
                self.active = set()
                r = m.solve(dict(fixed_support))
        force = np.zeros(3)
        force[2] = sum(r[3 * i + 2] for i in self.active)
        return force

    def _surface_points(self):
        """The top face sampled for the tilted punch's contact: on each 6-node face the lattice
        of barycentric points i/p, j/p (p = SURFACE_LATTICE, the face's nodes among them), each
        with the area its p² sub-triangles lump to it. Returns the sampling matrix S (points ×
        nodes; the points' positions are S x through the tri6 shape functions) and the areas."""
        if getattr(self, "_sampling", None) is None:
            self._sampling = surface_lattice(self.m.points, self.m.top_six, SURFACE_LATTICE)
        return self._sampling

    def _beside(self, tip, axis):
        """Which surface points are beside the disk (their distance from the shaft's line at
        least its radius less BESIDE_TOLERANCE_MM, so that a point the side wall holds stays
        beside) in the last converged state at this location, or in the current state at a
        location's first contact."""
        if self.beside is None:
            self._note_beside(tip, axis)
        return self.beside

    def _note_beside(self, tip, axis):
        S, _ = self._surface_points()
        d = S @ m_pos(self.m) - tip
        lat = np.linalg.norm(d - np.outer(d @ axis, axis), axis=1)
        self.beside = lat >= self.R - BESIDE_TOLERANCE_MM

    def _tilted(self, tip, axis, fixed_support):
        """Sticking tilted punch: an active set of surface points (`_surface_points`) inside the
        solid disk; each is anchored (punch frame) at its closest point on the disk's boundary
        when it touched (`disk_projection`: the face, or the side wall for a point nearer it)
        and a penalty k w on its full relative motion from there holds it; a point the punch
        would pull (tensile force along that normal) is released. Returns the force on the
        object."""
        m = self.m
        S, w = self._surface_points()
        k = self.k_pen
        beside = self._beside(tip, axis)
        for _ in range(8):
            x = S @ m_pos(m) - tip
            inside, normal, gap = disk_projection(x, axis, self.R, beside)
            add = {int(p) for p in np.flatnonzero(inside)} - self.active
            for p in add:
                self.anchor[p] = (x[p] - gap[p] * normal[p], normal[p])
            self.active |= add
            active = np.array(sorted(self.active), dtype=int)
            anchors = np.array([self.anchor[p][0] for p in active]).reshape(-1, 3)
            S3 = sp.kron(S[active], sp.eye(3), format="csr")
            kw = np.repeat(k * w[active], 3)

            def penalty(u, S3=S3, kw=kw, active=active, anchors=anchors):
                g = (S[active] @ (m.points + u) - tip - anchors).reshape(-1)
                f = S3.T @ (kw * g)
                K = (S3.T @ sp.diags(kw) @ S3).tocoo()
                return f, (K.row, K.col, K.data)

            m.solve(dict(fixed_support), penalty=penalty)
            fp = (kw * (S[active] @ m_pos(m) - tip - anchors).reshape(-1)).reshape(-1, 3)
            # release points the punch would pull (tensile force along the normal where they touched)
            pull = {int(p) for p, f in zip(active, fp) if -(f @ self.anchor[int(p)][1]) < 0.0}
            self.active -= pull
            for p in pull:
                self.anchor.pop(p, None)
            if not add and not pull:
                break
        active = np.array(sorted(self.active), dtype=int)
        if not len(active):
            self._note_beside(tip, axis)
            return np.zeros(3)
        anchors = np.array([self.anchor[p][0] for p in active])
        fp = k * w[active, None] * (S[active] @ m_pos(m) - tip - anchors)
        self._note_beside(tip, axis)
        return -fp.sum(axis=0)

    def _tilted_frictionless(self, tip, axis, fixed_support):
        """Frictionless tilted punch: a one-sided penalty k w g² / 2 on the gap g of every surface
        point (`_surface_points`) inside the solid disk, along the normal of the nearest part of
        its boundary (`disk_projection`): the face for a point nearer the face than the rim, the
        side wall otherwise. Material carried toward the shaft beside the low rim of the tilted
        disk is pushed back out through the wall (before, the punch had no side wall and such
        nodes were released: the surface passed into it). The tangent is the penalty's
        Gauss–Newton part k w (S n)(S n)ᵀ (the side wall's curvature term k w g/r (I − a aᵀ −
        n nᵀ) is dropped: at equilibrium g is the penalty's µm-scale penetration). Returns the
        force on the object."""
        m = self.m
        S, w = self._surface_points()
        k = self.k_pen
        R = self.R
        beside = self._beside(tip, axis)

        def contact(u):
            inside, normal, gap = disk_projection(S @ (m.points + u) - tip, axis, R, beside)
            idx = np.flatnonzero(inside)
            return idx, normal[idx], k * w[idx] * gap[idx]

        def penalty(u):
            idx, n, c = contact(u)
            Si = S[idx].tocoo()
            # B: one row per touching point, its normal spread over its nodes' x, y, z dofs
            rows = np.repeat(Si.row, 3)
            cols = 3 * np.repeat(Si.col, 3) + np.tile(np.arange(3), len(Si.col))
            vals = np.repeat(Si.data, 3) * n[Si.row].reshape(-1)
            B = sp.csr_matrix((vals, (rows, cols)), shape=(len(idx), 3 * m.n))
            f = B.T @ c
            K = (B.T @ sp.diags(k * w[idx]) @ B).tocoo()
            return f, (K.row, K.col, K.data)

        m.solve(dict(fixed_support), penalty=penalty)
        _, n, c = contact(m.u)
        self._note_beside(tip, axis)
        return -(c[:, None] * n).sum(axis=0)


SURFACE_LATTICE = 4
BESIDE_TOLERANCE_MM = 0.1


def surface_lattice(points, six, p):
    """Sampling of 6-node triangles at the barycentric lattice (i/p, j/p, 1 − i/p − j/p), each
    point weighted by a third of the area of each of the p² sub-triangles it is a corner of.
    Returns (S, w): S (points × nodes, sparse) the tri6 shape functions at the points (corner
    L(2L − 1), edge 4 Li Lj), w the points' areas (mm²; they sum to the faces' area)."""
    lat = [(i, j) for i in range(p + 1) for j in range(p + 1 - i)]
    index = {ij: q for q, ij in enumerate(lat)}
    share = np.zeros(len(lat))
    for i in range(p):
        for j in range(p - i):
            for v in ((i, j), (i + 1, j), (i, j + 1)):
                share[index[v]] += 1.0
            if i + j <= p - 2:
                for v in ((i + 1, j), (i, j + 1), (i + 1, j + 1)):
                    share[index[v]] += 1.0
    share /= 3.0 * p * p
    L = np.array([[i / p, j / p, 1.0 - (i + j) / p] for i, j in lat])
    L1, L2, L3 = L.T
    N = np.stack([L1 * (2 * L1 - 1), L2 * (2 * L2 - 1), L3 * (2 * L3 - 1),
                  4 * L1 * L2, 4 * L2 * L3, 4 * L3 * L1], axis=1)  # (q, 6), tri6 node order
    c = points[six[:, :3]]
    area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
    nq = len(lat)
    rows = np.repeat(np.arange(len(six) * nq), 6)
    cols = np.repeat(six, nq, axis=0).reshape(-1)
    vals = np.tile(N, (len(six), 1)).reshape(-1)
    S = sp.csr_matrix((vals, (rows, cols)), shape=(len(six) * nq, len(points)))
    S.eliminate_zeros()
    w = (area[:, None] * share[None, :]).reshape(-1)
    return S, w


def disk_projection(d, axis, radius, beside):
    """Projection of points inside the punch's solid disk onto its boundary, the gap along the
    normal of the projected point (Wriggers, Computational Contact Mechanics §4.1). `d` (n, 3):
    the points relative to the disk centre (tip); `axis`: the shaft's unit direction, pointing
    into the object. The solid: behind the face (d·axis < 0) within `radius` of the axis. A point
    can have entered the solid only through the face unless it was `beside` the disk (at least
    `radius` from the shaft's line) when the step started: those go out through the nearer of
    face and side wall (closest point), the others through the face. (The tilted disk's first
    contact puts its low rim 1.7 mm into the surface at once; a closest point would push the
    surface under the rim sideways.) Returns (inside (n,) bool, outward normal (n, 3) — the
    face's `axis` or the side wall's radial direction —, gap (n,) along it, negative inside)."""
    a = d @ axis
    v = d - np.outer(a, axis)
    lat = np.linalg.norm(v, axis=1)
    inside = (a < 0.0) & (lat < radius)
    side = inside & beside & (-a > radius - lat) & (lat > 1e-12)
    normal = np.tile(axis, (len(d), 1))
    gap = a.copy()
    normal[side] = v[side] / lat[side, None]
    gap[side] = lat[side] - radius
    return inside, normal, gap


def disk_intrusion(punch, tip, axis):
    """Deepest point of the sampled top face (`Punch._surface_points`) inside the punch's solid
    disk (mm along its nearest boundary's normal; 0 when none is inside): the contact
    constraint's violation, the penalty's compliance where the contact holds."""
    S, _ = punch._surface_points()
    everywhere = np.ones(S.shape[0], dtype=bool)
    inside, _, gap = disk_projection(S @ m_pos(punch.m) - tip, axis, punch.R, everywhere)
    return float(-gap[inside].min()) if inside.any() else 0.0


def m_pos(m):
    return m.points + m.u


def simulate(case, mesh10, marker_cells, marker_lams, log=print):
    """Solves every frame. Returns dict with frames (protocol), marker positions (f,k,3) mm, tip
    (f,3), axis (3,), force on the object (f,3) N, template marker positions (k,3) and the
    template node positions of the linear mesh (for volume.msh)."""
    points10, cells10, tags = mesh10
    frames, dt = protocol(case)
    height = case["geometry"]["size_mm"][-1]
    support = case.get("support", {"kind": "bonded"})
    model = Model(points10, cells10, tags, case["material"], dt, support, height)
    fixed_support = model.base_fixed()
    axis = np.array(case.get("probe_axis", [0.0, 0.0, -1.0]), float)
    axis /= np.linalg.norm(axis)
    punch = Punch(model, case["probe"]["radius_mm"], case["probe"].get("friction", "none"))
    E_scale = case["material"].get("mu", case["material"].get("E", 0.05) / 3.0)
    punch.k_pen = 2000.0 * E_scale
    if case.get("gravity_n_mm3") is not None:
        model.set_gravity(case["gravity_n_mm3"])
        model.solve(fixed_support)
        model.commit()
        log("  gravity pre-load solved")
    rest_u = model.u.copy()
    template_markers = m_pos_markers(model, cells10, marker_cells, marker_lams)
    surface_pts = []
    for loc in case["locations_mm"]:
        # surface point under the location along the shaft (top face, after any pre-load)
        surface_pts.append(surface_point(model, np.array([loc[0], loc[1], height]), axis))

    def recorded(markers, tips, forces):
        """The recording: the per-frame markers, tips and forces with what every case returns."""
        return {
            "frames": frames,
            "dt": dt,
            "markers": np.array(markers),
            "tips": np.array(tips),
            "axis": axis,
            "forces": np.array(forces),
            "template_markers": template_markers,
            "rest_u": rest_u,
        }

    rate_dependent = case["material"]["kind"] == "viscoelastic"
    if rate_dependent and not uniform_steps(case) and case["protocol"].get("control") == "force":
        raise ValueError(f"{case['name']}: a force-controlled viscoelastic material is integrated with one "
                         "time step; its protocol's frame steps differ (faster-ramps, rest-after-release)")
    path_dependent = (
        case["material"]["kind"] == "j2" and case["material"].get("yield") is not None
        or support["kind"] == "friction" or punch.friction == "stick"
    )
    if case["protocol"].get("control") == "force":
        if abs(axis[2] + 1.0) > 1e-9:
            raise ValueError(f"{case['name']}: force control is implemented for a vertical shaft only")
        punch.walled = True
        markers, tips, forces = force_controlled(case, frames, model, punch, axis, fixed_support, surface_pts,
                                                 lambda: m_pos_markers(model, cells10, marker_cells, marker_lams), log)
        return recorded(markers, tips, forces)
    cache = {}
    history = []
    markers, tips, forces, intrusion = [], [], [], []
    prev = None
    touch = touch_depth(punch.R, axis)
    for fi, fr in enumerate(frames):
        path = probe_path(case, surface_pts[fr["loc"]], axis)
        tip = path(fr["depth"])
        touching = fr["depth"] > touch
        key = (fr["loc"], round(max(fr["depth"], 0.0), 9)) if touching else ("free",)
        if prev is not None and key[0] != prev[0]:
            # a new location or lift-off: the punch starts without contact
            punch.active = set()
            punch.anchor = {}
            punch.beside = None
        same = prev == key
        if touching and (prev is None or prev[0] != key[0]):
            approach(model, punch, path, axis, fixed_support, history, fr["depth"])
        if touching and not same:
            predict(model, history, fr["loc"], fr["depth"])
        if rate_dependent:
            # the time the frame spans (frame periods: exact, `protocol`); the first frame one period
            step = round((fr["t"] - frames[fi - 1]["t"]) / dt, 9) if fi else 1.0
            model.set_time_step(step * dt)
            force = robust_step(model, punch, path, axis, fixed_support, history, fr["depth"], False, step * dt)
        elif path_dependent and not same:
            force = robust_step(model, punch, path, axis, fixed_support, history, fr["depth"], True)
        elif path_dependent:
            force = forces[-1].copy()
        elif key in cache:
            model.field[0].values[:] = cache[key][0]
            force = cache[key][1].copy()
        else:
            if touching:
                force = robust_step(model, punch, path, axis, fixed_support, history, fr["depth"], True)
            else:
                model.field[0].values[:] = rest_u
                force = np.zeros(3)
            cache[key] = (model.u.copy(), force.copy())
        prev = key
        history = (history + [(fr["loc"], fr["depth"], model.u.copy())])[-2:]
        markers.append(m_pos_markers(model, cells10, marker_cells, marker_lams))
        tips.append(tip)
        forces.append(force)
        intrusion.append(disk_intrusion(punch, tip, axis) if touching else 0.0)
        if fi % 20 == 0:
            log(f"  frame {fi}/{len(frames)}: depth {fr['depth']:.3f} mm, force {force[2]:.4f} N")
    deepest = int(np.argmax(intrusion))
    log(f"  deepest top-face point inside the punch's disk: {intrusion[deepest] * 1e3:.2f} µm (frame {deepest})")
    return recorded(markers, tips, forces)


# Force control: the secant iteration on the depth stops when the axial force is within this
# fraction of the location's peak of its target (1e-4 of the clean case's 1.42–2.08 N peaks:
# 0.14–0.21 mN, 1/300 of the diagnosis's 3 % hold-relaxation floor, signatures.rs
# HOLD_RELAXATION_FLOOR). Measured on slow-creep-g4-tau23s-force's first location: held forces
# 1.6525–1.6528 N for the target 1.652618 N.
FORCE_TOLERANCE = 1e-4
FORCE_MAX_ITER = 40
# The bracket of the force iteration below which its depth is taken as found, mm (1 nm).
DEPTH_TOLERANCE_MM = 1e-6
# Solves from the frame's committed depth to a trial depth at which Newton failed (force_step).
CONTINUATION_STEPS = 4
# A bracket narrower than this (mm) gives no slope for the next frame's first step (across a
# kink or jump its secant is no stiffness).
SLOPE_MIN_BRACKET_MM = 1e-3


def force_controlled(case, frames, model, punch, axis, fixed_support, surface_pts, markers_now, log):
    """The probing program under force control (the own rig's probe, docs/synth.md): on the
    ramps, holds and unloading ramps the punch is driven to the frame's target axial force
    (`protocol` force_n), not to a depth. Per frame a secant iteration on the depth of the
    vertical punch (each trial `Punch.step` from the frame's committed state and its active set)
    until |F − F_target| ≤ FORCE_TOLERANCE × peak, then one commit: one time step of the material
    per frame, as under position control. A rate-dependent body creeps under the held force (the
    tip sinks; the force stays flat), which is what the own rig's pair 1 records. Off the object
    (force_n None, and 0 at the end of the unloading ramp) the body is free; at force 0 the disk
    rests on the surface under it (its tip where the highest top node under the disk is).
    The punch is the walled disk (`Punch.walled`, the frictionless penalty contact of the tilted
    punch): with the vertical punch's nodal active set, a top node beside the rim that the
    nearly incompressible body pushes up above the disk's face is pulled down onto it once it
    passes under the rim, and F(depth) jumps there (slow-creep-g4-tau23s-force, location 2: from
    1.789 to 1.873 N between 2.38789 and 2.39113 mm, Newton failing on inverted tets in
    between, for the target 1.7938 N). The disk's side wall keeps such a node outside.
    Returns the frames' markers, tips and forces on the object."""
    markers, tips, forces = [], [], []
    prev_loc = None
    d_last, a_last, slope, creep = 0.0, 0.0, None, 0.0
    peaks = case["protocol"]["peak_force_n"]
    for fi, fr in enumerate(frames):
        loc = fr["loc"]
        path = probe_path(case, surface_pts[loc], axis)
        target = fr.get("force_n")
        if loc != prev_loc:
            punch.active, punch.anchor, punch.beside = set(), {}, None
            d_last, a_last, creep = 0.0, 0.0, 0.0
            slope = peaks[loc] / case["depths_mm"][loc]  # the location's secant stiffness, N/mm
        prev_loc = loc
        if target is None or target <= 0.0:
            force = free_step(model, punch, fixed_support)
            model.commit()
            if target is None:
                depth = fr["depth"]
                d_last, a_last, creep = 0.0, 0.0, 0.0
            else:
                depth = resting_depth(model, surface_pts[loc], punch.R)
        else:
            guess = d_last + (target - a_last) / slope + (creep if target == a_last else 0.0)
            force, depth, s = force_step(model, punch, path, axis, fixed_support, target, d_last, guess,
                                         slope, FORCE_TOLERANCE * peaks[loc])
            model.commit()
            if s is not None:
                slope = s
            creep = depth - d_last if target == a_last else 0.0
            d_last, a_last = depth, target
        markers.append(markers_now())
        tips.append(path(depth))
        forces.append(force)
        if fi % 20 == 0:
            log(f"  frame {fi}/{len(frames)}: depth {depth:.4f} mm, force {force[2]:.4f} N (target {target})")
    return markers, tips, forces


def force_step(model, punch, path, axis, fixed_support, target, start, guess, slope, tol):
    """The depth at which the vertical punch's axial force is `target` (N): a safeguarded secant
    (regula falsi, Illinois variant, inside a bracket; a bisection when a step leaves it) from
    `guess`, the bracket found by steps of the slope `slope` (N/mm). Every trial is solved from the
    frame's starting contact state (`Punch.step`: its active set and which surface points are
    beside the disk; `Model.solve` starts from the last committed inelastic state). F(depth) is
    continuous but has a kink wherever the contact grows: a plain secant (this function's first
    version) oscillated there without converging (slow-creep-g4-tau23s-force, location 2: 1.4883 N
    at 1.92694 mm for 1.4350 N after 12 steps). The bracket shrinking below DEPTH_TOLERANCE_MM ends
    it too. Newton failing at a trial depth: the trial again, Newton started from the frame's
    committed state (depth `start`) moved there in CONTINUATION_STEPS solves (only Newton's
    starting point changes: each is from the committed inelastic state); failing again, the trial
    is halved towards the nearest converged one (plastic-force with the walled punch: its first
    unloading frame, 1.46 → 1.17 mm, failed from the held state). Returns (force on the object,
    depth, the last secant slope or None)."""
    from .physics import NotConverged

    if punch.beside is None:
        punch._note_beside(path(guess), axis)  # from the frame's committed state
    active0, beside0 = set(punch.active), punch.beside.copy()
    u0 = model.u.copy()

    def axial_at(d):
        punch.active, punch.anchor, punch.beside = set(active0), {}, beside0.copy()
        f = punch.step(path(d), axis, fixed_support)
        return f, float(f @ axis)

    def axial_continued(d):
        model.field[0].values[:] = u0
        for k in range(1, CONTINUATION_STEPS + 1):
            f, a = axial_at(start + (d - start) * k / CONTINUATION_STEPS)
        return f, a

    lo = hi = None  # (depth, force - target), below and above the target
    best = None
    d, a = guess, None
    side, grow = 0, 1.0
    for _ in range(FORCE_MAX_ITER):
        try:
            try:
                f, a = axial_at(d)
            except NotConverged:
                f, a = axial_continued(d)
        except NotConverged:
            if os.environ.get("TP_DEBUG"):
                print(f"    force trial at {d:.7f} mm: Newton failed", file=sys.stderr)
            model.field[0].values[:] = u0
            ref = lo if lo is not None else hi
            d = 0.5 * (d + (ref[0] if ref is not None else max(guess - 0.1, 0.0)))
            continue
        r = a - target
        if os.environ.get("TP_DEBUG"):
            print(f"    force trial at {d:.7f} mm: {a:.6f} N ({r:+.6f})", file=sys.stderr)
        if best is None or abs(r) < abs(best[1]):
            best = (d, r)
        if abs(r) <= tol:
            break
        if r < 0.0:
            lo = (d, r)
            if side == -1 and hi is not None:
                hi = (hi[0], hi[1] / 2)  # Illinois: halve the stale end
            side = -1
        else:
            hi = (d, r)
            if side == 1 and lo is not None:
                lo = (lo[0], lo[1] / 2)
            side = 1
        if lo is None or hi is None:
            d = d - grow * r / slope  # still looking for the bracket: steps doubling
            grow *= 2.0
            continue
        if hi[0] - lo[0] <= DEPTH_TOLERANCE_MM:
            break
        d = lo[0] - lo[1] * (hi[0] - lo[0]) / (hi[1] - lo[1])
        if not lo[0] < d < hi[0]:
            d = 0.5 * (lo[0] + hi[0])
    else:
        raise NotConverged(f"force control: {a} N at depth {d:.5f} mm, target {target:.6f} N")
    if best[0] != d:  # the closest trial was not the last one: solve it again as the state
        f, a = axial_at(best[0])
    s = None
    if lo is not None and hi is not None and hi[0] - lo[0] > SLOPE_MIN_BRACKET_MM:
        s = (hi[1] - lo[1]) / (hi[0] - lo[0])
    return f, best[0], s if s is not None and s > 0.0 else None


def resting_depth(model, surface, radius):
    """The depth of a flat disk resting without force on the current top face at `surface`: the
    nominal surface's height less the highest top node within `radius` of the vertical shaft."""
    x = m_pos(model)[model.top]
    near = np.linalg.norm(x[:, :2] - surface[:2], axis=1) <= radius
    return float(surface[2] - x[near, 2].max()) if near.any() else 0.0


def robust_step(model, punch, path, axis, fixed_support, history, depth, may_substep, dtime=None):
    """One frame's equilibrium, committed (one time step of the inelastic state), the tip at
    `path(depth)` (`probe_path`); when Newton fails, again from the last converged state without
    the predictor, then in four committed substeps of the punch motion along its path: for a
    rate-independent material (`may_substep`), or a rate-dependent one given the frame's time
    step `dtime` (each substep a quarter of it: the frame's time integrated in four steps)."""
    from .physics import NotConverged

    def once(t, d):
        touching = d > touch_depth(punch.R, axis)
        force = punch.step(t, axis, fixed_support) if touching else free_step(model, punch, fixed_support)
        model.commit()
        return force

    tip = path(depth)
    active, anchor, beside = set(punch.active), dict(punch.anchor), punch.beside
    try:
        return once(tip, depth)
    except NotConverged:
        pass
    if not history:
        raise NotConverged("first frame")
    _, d_prev, u_prev = history[-1]
    model.field[0].values[:] = u_prev
    punch.active, punch.anchor, punch.beside = set(active), dict(anchor), beside
    try:
        return once(tip, depth)
    except NotConverged:
        if not may_substep and dtime is None:
            raise
    model.field[0].values[:] = u_prev
    punch.active, punch.anchor, punch.beside = set(active), dict(anchor), beside
    force = None
    if dtime is not None:
        model.set_time_step(dtime / 4)
    try:
        for k in range(1, 5):
            d = d_prev + (depth - d_prev) * k / 4
            force = once(path(d), d)
    finally:
        if dtime is not None:
            model.set_time_step(dtime)
    return force


APPROACH_STEP_MM = 0.5


def probe_path(case, surface, axis):
    """The tip's position (disk centre, mm) as a function of the depth d along the shaft below
    the surface point `surface`: surface + d axis, plus, when the protocol has a `slide`
    (probe-friction and its pair), a sideways travel `ratio` × max(d, 0) along its unit
    direction `dir`, the same on the way in and on the way out: an oblique push, the path a
    user's hand takes when it presses in at an angle to the shaft (the own rig's probe-friction
    path, `friction_path_ratio`)."""
    slide = case["protocol"].get("slide")
    if slide is None:
        return lambda d: surface + d * axis
    direction = np.array(slide["dir"], float)
    direction /= np.linalg.norm(direction)
    return lambda d: surface + d * axis + slide["ratio"] * max(d, 0.0) * direction


def touch_depth(radius, axis):
    """The depth along the shaft (below the surface point under the disk centre) at which the
    disk first meets a flat top face: 0 for a vertical shaft, −R tan θ for a shaft θ from the
    vertical (its low rim reaches the surface first)."""
    sin = np.sqrt(max(1.0 - axis[2] ** 2, 0.0))
    return -radius * sin / -axis[2]


def approach(model, punch, path, axis, fixed_support, history, depth):
    """A tilted disk's first contact at a location: a frame that jumps from hovering to a depth
    d puts the low rim d − `touch_depth` into the surface at once. The punch instead travels from
    its first touch to d in committed steps of at most APPROACH_STEP_MM (the sticking disk's
    points stick where they touch on the way). A vertical punch touches with its whole face at
    depth 0: nothing to do."""
    touch = touch_depth(punch.R, axis)
    if touch > -1e-9:
        return
    n = int(np.ceil((depth - touch) / APPROACH_STEP_MM))
    for k in range(1, n):
        d = touch + (depth - touch) * k / n
        robust_step(model, punch, path, axis, fixed_support, history, d, True)


def predict(model, history, loc, depth):
    """Newton's starting point: the displacements extrapolated linearly in depth from the last two
    frames when both pressed at the same location (the punch's step alone is a jump)."""
    if len(history) < 2:
        return
    (l1, d1, u1), (l2, d2, u2) = history
    if l1 != loc or l2 != loc or d1 <= 0 or d2 <= 0 or abs(d2 - d1) < 1e-12:
        return
    model.field[0].values[:] = u2 + (depth - d2) / (d2 - d1) * (u2 - u1)


def free_step(model, punch, fixed_support):
    punch.active = set()
    punch.anchor = {}
    punch.beside = None
    model.solve(dict(fixed_support))
    return np.zeros(3)


def m_pos_markers(model, cells10, marker_cells, marker_lams):
    X = interpolate_markers(model.points, cells10, marker_cells, marker_lams)
    return X + interpolate_markers(model.u, cells10, marker_cells, marker_lams)


def surface_point(model, guess, axis):
    """Where the shaft line through `guess` meets the current top face: the current z of the
    top nodes nearest the line (a flat face, or one sagged by gravity)."""
    x = m_pos(model)[model.top]
    d = np.linalg.norm((x - guess)[:, :2], axis=1)
    near = np.argsort(d)[:6]
    w = 1.0 / (d[near] + 1e-6)
    z = float((x[near, 2] * w).sum() / w.sum())
    # move along the axis from the vertical point to z (axis never horizontal)
    p = np.array([guess[0], guess[1], z])
    return p
