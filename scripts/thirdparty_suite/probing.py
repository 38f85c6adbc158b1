"""The probing protocol and its quasi-static solution, frame by frame.

Per location: the probe hovers above the location, ramps down to its depth, holds, ramps back up
to the surface, lifts off and moves to the next location. Frame 0 is the rest state with the probe
hovering above the first location. The punch is a rigid flat disk with a sharp edge:
- vertical shaft: an active set of top-face nodes under the disk take the punch's z displacement
  (frictionless: their x, y are free); nodes that penetrate the face are added; when the total
  force turns tensile the punch has lost contact and the set is emptied;
- tilted shaft (probe friction case and its pair): the disk face is perpendicular to the shaft and
  contact is a penalty on the nodes under the disk: a one-sided penalty on the normal gap of the
  nodes nearer the face than the rim (frictionless), or on an active set's full relative motion
  from where each node touched (sticking friction).
"""
import numpy as np

from .physics import Model, interpolate_markers


def protocol(case):
    """Frame list: dicts with t (s), loc (index or None), depth_mm along the shaft below the
    surface point (negative: hovering), phase name."""
    p = case["protocol"]
    dt = 1.0 / p["fps"]
    frames = []

    def add(loc, depth, phase):
        frames.append({"t": len(frames) * dt, "loc": loc, "depth": depth, "phase": phase})

    hover = -p["hover_mm"]
    add(0, hover, "rest")
    for li, dmax in enumerate(case["depths_mm"]):
        for _ in range(p["approach"]):
            add(li, hover, "approach")
        n = p["ramp"]
        for k in range(1, n + 1):
            add(li, dmax * k / n, "ramp")
        for _ in range(p["hold"]):
            add(li, dmax, "hold")
        n = p["unload"]
        for k in range(n - 1, -1, -1):
            add(li, dmax * k / n, "unload")
        for _ in range(p["release"]):
            add(li, hover, "release")
    return frames, dt


class Punch:
    """Rigid flat punch acting on a Model."""

    def __init__(self, model, radius, friction):
        self.m = model
        self.R = radius
        self.friction = friction  # "none" | "stick"
        self.active = set()
        self.anchor = {}
        self.k_pen = None

    def step(self, tip, axis, fixed_support):
        m = self.m
        vertical = abs(axis[2] + 1.0) < 1e-9
        if vertical:
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

    def _tilted(self, tip, axis, fixed_support):
        m = self.m
        k = self.k_pen
        for _ in range(8):
            ids, along, lat = self._candidates(tip, axis)
            add = {int(i) for i, a, l in zip(ids, along, lat) if l <= self.R and a < 0.0} - self.active
            for i in add:
                x = m_pos(m)[i]
                y = x - tip
                self.anchor[i] = y - (y @ axis) * axis
            self.active |= add
            active = sorted(self.active)

            def penalty(u, active=active):
                f = np.zeros(3 * m.n)
                rows, cols, vals = [], [], []
                for i in active:
                    A = m.top_area[i]
                    x = m.points[i] + u[i]
                    g = x - tip - self.anchor[i]
                    f[3 * i:3 * i + 3] = k * A * g
                    K = k * A * np.eye(3)
                    for a in range(3):
                        for b in range(3):
                            rows.append(3 * i + a)
                            cols.append(3 * i + b)
                            vals.append(K[a, b])
                return f, (rows, cols, vals)

            m.solve(dict(fixed_support), penalty=penalty)
            fp, _ = penalty(m.u)
            # release nodes the punch would pull (tensile normal force)
            pull = {i for i in active if -(fp[3 * i:3 * i + 3] @ axis) < 0.0}
            self.active -= pull
            for i in pull:
                self.anchor.pop(i, None)
            if not add and not pull:
                break
        fp, _ = penalty(m.u, sorted(self.active))
        force = np.zeros(3)
        for i in self.active:
            force -= fp[3 * i:3 * i + 3]
        return force

    def _tilted_frictionless(self, tip, axis, fixed_support):
        """Frictionless tilted punch: a one-sided penalty on the normal gap of every top node
        under the disk face, the face being the contact geometry of the sticking punch too (no
        side wall). A node counts as under the face while it is nearer the face than the rim
        (penetration along the shaft ≤ R − lateral distance): the surface slides along the face
        toward the sharp low edge, and material carried past the rim (behind the face from its
        side) takes no load: the punch has no side wall, frictionless or sticking, and its force
        stays along the shaft. With an active set of face nodes (as the sticking punch has),
        such material joined the set deep behind the face and Newton diverged (location 4,
        2 mm). Returns the force on the object."""
        m = self.m
        top = m.top
        kA = self.k_pen * m.top_area[top]
        R = self.R
        K1 = np.outer(axis, axis)

        def penalty(u):
            d = m.points[top] + u[top] - tip
            a = d @ axis
            lat = np.linalg.norm(d - np.outer(a, axis), axis=1)
            f = np.zeros(3 * m.n)
            rows, cols, vals = [], [], []
            for j in np.flatnonzero((a < 0.0) & (-a <= R - lat)):
                i = top[j]
                f[3 * i:3 * i + 3] = kA[j] * a[j] * axis
                for r in range(3):
                    for c in range(3):
                        rows.append(3 * i + r)
                        cols.append(3 * i + c)
                        vals.append(kA[j] * K1[r, c])
            return f, (rows, cols, vals)

        m.solve(dict(fixed_support), penalty=penalty)
        fp, _ = penalty(m.u)
        return -fp.reshape(-1, 3).sum(axis=0)


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
    rate_dependent = case["material"]["kind"] == "viscoelastic"
    path_dependent = (
        case["material"]["kind"] == "j2" and case["material"].get("yield") is not None
        or support["kind"] == "friction" or punch.friction == "stick"
    )
    cache = {}
    history = []
    markers, tips, forces = [], [], []
    prev = None
    for fi, fr in enumerate(frames):
        tip = surface_pts[fr["loc"]] + fr["depth"] * axis
        key = (fr["loc"], round(max(fr["depth"], 0.0), 9))
        if fr["depth"] <= 0.0:
            key = ("free",)
        if prev is not None and key[0] != prev[0]:
            # a new location or lift-off: the punch starts without contact
            punch.active = set()
            punch.anchor = {}
        same = prev == key
        if fr["depth"] > 0 and not same:
            predict(model, history, fr["loc"], fr["depth"])
        if rate_dependent or (path_dependent and not same):
            force = robust_step(model, punch, tip, axis, fixed_support, history, fr["depth"], not rate_dependent)
        elif path_dependent:
            force = forces[-1].copy()
        elif key in cache:
            model.field[0].values[:] = cache[key][0]
            force = cache[key][1].copy()
        else:
            if fr["depth"] > 0:
                force = robust_step(model, punch, tip, axis, fixed_support, history, fr["depth"], True)
            else:
                model.field[0].values[:] = rest_u
                force = np.zeros(3)
            cache[key] = (model.u.copy(), force.copy())
        prev = key
        history = (history + [(fr["loc"], fr["depth"], model.u.copy())])[-2:]
        markers.append(m_pos_markers(model, cells10, marker_cells, marker_lams))
        tips.append(tip)
        forces.append(force)
        if fi % 20 == 0:
            log(f"  frame {fi}/{len(frames)}: depth {fr['depth']:.3f} mm, force {force[2]:.4f} N")
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


def robust_step(model, punch, tip, axis, fixed_support, history, depth, may_substep):
    """One frame's equilibrium, committed (one time step of the inelastic state); when Newton
    fails, again from the last converged state without the predictor, then (rate-independent
    materials only) in four committed substeps of the punch motion."""
    from .physics import NotConverged

    def once(t, d):
        force = punch.step(t, axis, fixed_support) if d > 0 else free_step(model, punch, fixed_support)
        model.commit()
        return force

    active, anchor = set(punch.active), dict(punch.anchor)
    try:
        return once(tip, depth)
    except NotConverged:
        pass
    if not history:
        raise NotConverged("first frame")
    _, d_prev, u_prev = history[-1]
    model.field[0].values[:] = u_prev
    punch.active, punch.anchor = set(active), dict(anchor)
    try:
        return once(tip, depth)
    except NotConverged:
        if not may_substep:
            raise
    model.field[0].values[:] = u_prev
    punch.active, punch.anchor = set(active), dict(anchor)
    start = tip - (depth - d_prev) * axis
    force = None
    for k in range(1, 5):
        d = d_prev + (depth - d_prev) * k / 4
        force = once(start + (d - d_prev) * axis, d)
    return force


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
