"""Quasi-static probing solved with FElupe on quadratic tetrahedra (tetra10).

The Newton loop is written here (FElupe assembles the hyperelastic/inelastic bodies); on top of
it come the boundary conditions that make the truth: the support (bonded, or a frictional base
with a regularized Coulomb law), a rigid flat punch with a sharp edge (an active set of top-face
nodes that take the punch's displacement while it is in contact; a penalty form for the tilted
probe), gravity as a body force. Units: mm, N, MPa (N/mm²), s.
"""
import os
import sys

import numpy as np
import felupe as fem
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .geometry import boundary_triangles, tet10_shape


class NotConverged(RuntimeError):
    pass


def dense(v):
    return np.asarray(v.toarray() if sp.issparse(v) else v).ravel()


def hgo_like(C, mu, k1, k2, fibres):
    """Neo-Hooke matrix (isochoric) plus HGO fibre terms k1/(2 k2) (exp(k2 (I4 − 1)²) − 1) for
    each fibre direction (here active in tension and compression; Holzapfel–Gasser–Ogden 2000
    switch off compressed fibres)."""
    import tensortrax.math as tm

    J3 = tm.linalg.det(C) ** (-1 / 3)
    W = mu / 2 * (J3 * tm.trace(C) - 3)
    for a in fibres:
        A = np.outer(a, a)
        I4 = tm.trace(C @ A)
        W = W + k1 / (2 * k2) * (tm.exp(k2 * (I4 - 1) ** 2) - 1)
    return W


def materials(spec, ncells, tags, dtime):
    """FElupe constitutive models of a material spec (summed bodies)."""
    kind = spec["kind"]
    if kind == "neo-hooke":
        mu = np.where(tags == 1, spec.get("mu_inclusion", spec["mu"]), spec["mu"])
        return [fem.NeoHooke(mu=mu, bulk=spec["bulk"] * mu / spec["mu"])]
    if kind == "yeoh":
        return [
            fem.Hyperelastic(fem.yeoh, C10=spec["C10"], C20=spec["C20"], C30=spec["C30"]),
            fem.Volumetric(bulk=spec["bulk"]),
        ]
    if kind == "viscoelastic":
        # the equilibrium branch takes the inclusion's shear modulus (`mu_inclusion`) as neo-hooke does
        mu = np.where(tags == 1, spec.get("mu_inclusion", spec["mu"]), spec["mu"])
        out = [fem.NeoHooke(mu=mu, bulk=spec["bulk"] * mu / spec["mu"])]
        for mu_i, tau_i in spec["branches"]:
            out.append(
                fem.Hyperelastic(
                    fem.finite_strain_viscoelastic,
                    mu=mu_i, eta=mu_i * tau_i, dtime=dtime, nstatevars=6,
                )
            )
        return out
    if kind == "hgo":
        fib = [np.array(f, float) / np.linalg.norm(f) for f in spec["fibres"]]
        return [
            fem.Hyperelastic(hgo_like, mu=spec["mu"], k1=spec["k1"], k2=spec["k2"], fibres=fib),
            fem.Volumetric(bulk=spec["bulk"]),
        ]
    if kind == "j2":
        # J2 plasticity with linear isotropic hardening, small-strain kinematics (FElupe
        # MaterialStrain; the total-Lagrange variant is St. Venant–Kirchhoff-based and loses
        # stability under the punch edge's compression).
        E, nu = spec["E"], spec["nu"]
        lmbda = E * nu / ((1 + nu) * (1 - 2 * nu))
        mu = E / (2 * (1 + nu))
        if spec.get("yield") is None:
            return [fem.MaterialStrain(fem.linear_elastic, μ=mu, λ=lmbda, framework="small-strain")]
        return [
            fem.MaterialStrain(
                fem.linear_elastic_plastic_isotropic_hardening,
                λ=lmbda, μ=mu, σy=spec["yield"], K=spec["hardening"],
                dim=3, statevars=(1, (3, 3)), framework="small-strain",
            )
        ]
    raise ValueError(f"unknown material {kind}")


class Model:
    """The object, its material and supports, ready to be probed."""

    def __init__(self, points10, cells10, tags, material, dtime, support, height):
        self.mesh = fem.Mesh(points10, cells10, "tetra10")
        self.region = fem.RegionQuadraticTetra(self.mesh)
        self.field = fem.FieldContainer([fem.Field(self.region, dim=3)])
        self.bodies = [
            fem.SolidBody(m, self.field) for m in materials(material, len(cells10), tags, dtime)
        ]
        for b in self.bodies:
            # Viscous branches start relaxed: inelastic C_i = identity (upper triangle 1,0,0,1,0,1).
            if b.results.statevars is not None and b.results.statevars.shape[0] == 6:
                b.results.statevars[[0, 3, 5]] = 1.0
        self.points = points10
        self.n = len(points10)
        self.height = height
        self.support = support
        self.body_force = np.zeros(3 * self.n)
        tris = boundary_triangles(cells10[:, :4])
        self.base = np.unique(np.concatenate(
            [self._tri6(cells10, tris[np.all(points10[tris][:, :, 2] < 1e-6, axis=1)])]
        ))
        top_tris = tris[np.all(np.abs(points10[tris][:, :, 2] - height) < 1e-6, axis=1)]
        self.top = np.unique(self._tri6(cells10, top_tris))
        self.top_area = self._lumped_area(cells10, top_tris)
        self.top_six = self._tri6(cells10, top_tris).reshape(-1, 6)  # the top faces' tri6 nodes
        base_tris = tris[np.all(points10[tris][:, :, 2] < 1e-6, axis=1)]
        self.base_area = self._lumped_area(cells10, base_tris)
        self.base_cells = self._cells_on(cells10, base_tris)
        self.slip = np.zeros((self.n, 2))  # committed slip of the frictional base
        self.last_pressure = np.zeros(self.n)
        self.stick_anchor = {}  # tilted punch with friction: node → anchor in the punch frame

    def _edge_mid(self, cells10):
        if not hasattr(self, "_mid"):
            e = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]
            self._mid = {}
            for c in cells10:
                for k, (i, j) in enumerate(e):
                    self._mid[(min(c[i], c[j]), max(c[i], c[j]))] = c[4 + k]
        return self._mid

    def _tri6(self, cells10, tris):
        mid = self._edge_mid(cells10)
        out = []
        for t in tris:
            out.extend(t)
            for i, j in ((0, 1), (1, 2), (2, 0)):
                out.append(mid[(min(t[i], t[j]), max(t[i], t[j]))])
        return np.array(out, dtype=int)

    def _lumped_area(self, cells10, tris):
        """Area lumped to the 6 nodes of each face (A/6 each)."""
        area = np.zeros(self.n)
        six = self._tri6(cells10, tris).reshape(-1, 6)
        for t, s in zip(tris, six):
            p = self.points[t]
            a = 0.5 * np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]))
            area[s] += a / 6
        return area

    def _cells_on(self, cells10, tris):
        """For each base face: (cell index, its 6 nodes, area)."""
        key = {tuple(sorted(c[list(f)])): ci for ci, c in enumerate(cells10[:, :4])
               for f in ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1))}
        six = self._tri6(cells10, tris).reshape(-1, 6)
        out = []
        for t, s in zip(tris, six):
            p = self.points[t]
            out.append((key[tuple(sorted(t))], s, 0.5 * np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]))))
        return out

    def set_gravity(self, rho_g_n_mm3):
        """Body force density (N/mm³, world vector) integrated with the element's quadrature."""
        load = fem.SolidBodyForce(self.field, values=np.array(rho_g_n_mm3, float))
        self.body_force = dense(load.assemble.vector(self.field))

    @property
    def u(self):
        return self.field[0].values

    # --- internal forces -------------------------------------------------------------------
    def _assemble(self, matrix=True):
        r = sum(dense(b.assemble.vector(self.field)) for b in self.bodies)
        K = sum(b.assemble.matrix(self.field) for b in self.bodies).tocsr() if matrix else None
        return r, K

    def _base_pressure(self):
        """Compressive normal traction at each base node from the stress of the cells on the base
        (first Piola P_zz, averaged over the cell's quadrature points, area-weighted to nodes)."""
        P = sum(b.results.stress[0] for b in self.bodies)  # (3,3,q,c)
        pzz = -P[2, 2].mean(axis=0)
        p = np.zeros(self.n)
        w = np.zeros(self.n)
        for ci, six, a in self.base_cells:
            p[six] += a * pzz[ci]
            w[six] += a
        ok = w > 0
        p[ok] /= w[ok]
        return np.maximum(p, 0.0)

    def _friction(self, u, pressure, commit=False):
        """Regularized Coulomb base: per base node a tangential spring k_t·A against the committed
        slip, its force smoothly capped at the Coulomb limit L = μ (p + p_weight) A,
        f = L tanh(|t|/L) t/|t| with the trial force t = k_t A (u − slip) (the smooth cap keeps
        Newton's method convergent); returns (force (3n), tangent triplets). Committing a step
        moves the slip so that the spring carries exactly the capped force."""
        s = self.support
        kt, mu_f, p0 = s["k_t"], s["mu"], s.get("p_weight", 0.0)
        f = np.zeros(3 * self.n)
        rows, cols, vals = [], [], []
        for i in self.base:
            A = self.base_area[i]
            if A <= 0:
                continue
            k = kt * A
            trial = k * (u[i, :2] - self.slip[i])
            lim = mu_f * (pressure[i] + p0) * A
            nt = np.linalg.norm(trial)
            x = nt / lim
            if x < 1e-8:
                force, tang = trial, k * np.eye(2)
            else:
                n = trial / nt
                th = np.tanh(x)
                force = lim * th * n
                tang = k * ((1 - th * th) * np.outer(n, n) + (th / x) * (np.eye(2) - np.outer(n, n)))
            f[3 * i:3 * i + 2] = force
            for a in range(2):
                for b in range(2):
                    rows.append(3 * i + a)
                    cols.append(3 * i + b)
                    vals.append(tang[a, b])
            if commit:
                self.slip[i] = u[i, :2] - force / k
        return f, (rows, cols, vals)

    # --- one quasi-static step -----------------------------------------------------------------
    def solve(self, fixed, penalty=None, tol=1e-7, max_iter=30):
        """Newton iteration to equilibrium with prescribed displacements `fixed` (dict dof → value)
        and an optional penalty callback (u → (force (3n), (rows, cols, vals))), starting from the
        last committed inelastic state (see `commit`). Returns the internal force vector
        (reactions at the fixed dofs)."""
        u = self.u.reshape(-1)
        dofs = np.array(sorted(fixed), dtype=int)
        vals = np.array([fixed[d] for d in dofs])
        u[dofs] = vals
        free = np.setdiff1d(np.arange(3 * self.n), dofs)
        friction = self.support["kind"] == "friction"
        if friction:
            bz = 3 * self.base + 2
            free = np.setdiff1d(free, bz)
            u[bz] = 0.0
        # the friction limit uses the base pressure of the last converged state (staggered)
        pressure = self.last_pressure if friction else None
        du, halvings, last_norm = None, 0, np.inf
        for it in range(max_iter):
            r, K = self._assemble()
            if not np.all(np.isfinite(r)) and du is not None and halvings < 8:
                # the full Newton step inverted an element: halve it
                du *= 0.5
                u[free] -= du
                halvings += 1
                continue
            r = r - self.body_force
            extra = []
            if friction:
                fr, trip = self._friction(self.u, pressure)
                r = r + fr
                extra.append(trip)
            if penalty is not None:
                fp, trip = penalty(self.u)
                r = r + fp
                extra.append(trip)
            for rows, cols, v in extra:
                if len(rows):
                    K = K + sp.csr_matrix((v, (rows, cols)), shape=K.shape)
            rf = r[free]
            if du is not None and halvings < 8 and np.linalg.norm(rf) > 4.0 * last_norm:
                # backtracking: the residual grew, halve the step
                du *= 0.5
                u[free] -= du
                halvings += 1
                continue
            last_norm = np.linalg.norm(rf)
            scale = max(1.0, np.abs(r).max())
            if os.environ.get("TP_DEBUG"):
                print(f"    it {it} |r| {np.linalg.norm(rf):.3e}", file=sys.stderr)
            if np.linalg.norm(rf) < tol * scale and it > 0:
                break
            if friction and it >= 6 and np.linalg.norm(rf) < 1e-3 * scale:
                # the smooth Coulomb cap of nodes at (almost) zero pressure flips its direction
                # from one iterate to the next: a residual of 1e-3 of the largest force is kept
                break
            try:
                du = spla.spsolve(K[free][:, free].tocsc(), -rf)
            except RuntimeError as e:  # SuperLU: a non-finite or singular tangent
                raise NotConverged(str(e)) from e
            if not np.all(np.isfinite(du)):
                raise NotConverged("singular tangent")
            u[free] += du
            if np.linalg.norm(du) < 1e-10 and it > 0:
                break
        else:
            raise NotConverged(f"no equilibrium after {max_iter} Newton iterations (|r| = {np.linalg.norm(rf):.3g} N)")
        return r

    def set_time_step(self, dtime):
        """The time step of the next commits (s): the Maxwell branches' `dtime` (a rate-dependent
        material integrates each frame, or each substep of one, with the time it spans)."""
        for b in self.bodies:
            if "dtime" in getattr(b.umat, "kwargs", {}):
                b.umat.kwargs["dtime"] = dtime

    def commit(self):
        """Ends a load step at the current (converged) state: the inelastic state variables
        (Maxwell branches, plastic strain) and the base's slip move on. Called once per frame (per
        substep), never between the active-set iterations of one frame: each commit advances the
        viscous branches by one time step."""
        for b in self.bodies:
            b.results.update_statevars()
        if self.support["kind"] == "friction":
            self._friction(self.u, self.last_pressure, commit=True)
            self.last_pressure = self._base_pressure()

    def base_fixed(self):
        """Dirichlet dofs of the support: bonded base → all dofs of base nodes (friction base: the
        z dofs are handled in `solve`)."""
        if self.support["kind"] == "bonded":
            return {3 * i + k: 0.0 for i in self.base for k in range(3)}
        return {}


def interpolate_markers(u, cells10, marker_cells, marker_lams):
    """Displacements at the markers (quadratic interpolation inside their tets)."""
    N = tet10_shape(marker_lams)  # (k,10)
    return np.einsum("ka,kad->kd", N, u[cells10[marker_cells]])
