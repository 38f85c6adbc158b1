"""Object geometry: gmsh meshes (linear tets, written as the session's template) and their
quadratic refinement for FElupe, plus marker placement and quadratic interpolation at markers.

Lengths are millimetres. The support plane is z = 0 and the object's top face is z = height.
"""
import numpy as np


def mesh_object(shape, size_mm, h_top_mm, h_bottom_mm, inclusion=None):
    """Meshes the object with gmsh (Delaunay, linear tets; finer at the top where the punch
    acts). `shape` is "block" (size = [lx, ly, lz], corner at the origin) or "cylinder"
    (size = [radius, height], axis through (radius, radius)). `inclusion` = (centre, radius)
    adds a spherical region whose tets are tagged 1 (others 0).

    Returns (points (n,3), tets (m,4) int, tag (m,) int)."""
    import gmsh

    gmsh.initialize(["-noenv"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.option.setNumber("Mesh.RandomSeed", 0.0)
        gmsh.model.add("object")
        occ = gmsh.model.occ
        if shape == "block":
            lx, ly, lz = size_mm
            body = occ.addBox(0, 0, 0, lx, ly, lz)
        elif shape == "cylinder":
            r, lz = size_mm
            body = occ.addCylinder(r, r, 0, 0, 0, lz, r)
        else:
            raise ValueError(f"unknown shape {shape}")
        inc_tag = None
        if inclusion is not None:
            c, rad = inclusion
            inc_tag = occ.addSphere(c[0], c[1], c[2], rad)
            out, _ = occ.fragment([(3, body)], [(3, inc_tag)])
        occ.synchronize()
        vols = [t for d, t in gmsh.model.getEntities(3)]
        lz = size_mm[-1]
        # Element size grows linearly from the top face down.
        field = gmsh.model.mesh.field
        f = field.add("MathEval")
        field.setString(
            f, "F", f"{h_bottom_mm} + ({h_top_mm} - {h_bottom_mm}) * z / {lz}"
        )
        field.setAsBackgroundMesh(f)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm3D", 1)
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.model.mesh.generate(3)
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        index = {int(t): i for i, t in enumerate(node_tags)}
        points = coords.reshape(-1, 3)
        tets, tags = [], []
        for v in vols:
            etypes, _, enodes = gmsh.model.mesh.getElements(3, v)
            is_inc = 0
            if inclusion is not None:
                # the inclusion is the fragment whose volume is the sphere's
                sphere = 4.0 / 3.0 * np.pi * inclusion[1] ** 3
                is_inc = int(abs(gmsh.model.occ.getMass(3, v) - sphere) < 1e-3 * sphere)
            for et, en in zip(etypes, enodes):
                if et != 4:
                    continue
                cells = np.array([index[int(t)] for t in en]).reshape(-1, 4)
                tets.append(cells)
                tags.append(np.full(len(cells), is_inc))
    finally:
        gmsh.finalize()
    tets = np.concatenate(tets)
    tags = np.concatenate(tags)
    used = np.unique(tets)
    remap = -np.ones(len(points), dtype=int)
    remap[used] = np.arange(len(used))
    points = points[used]
    tets = remap[tets]
    # Positive orientation.
    d = np.einsum(
        "ij,ij->i",
        np.cross(points[tets[:, 1]] - points[tets[:, 0]], points[tets[:, 2]] - points[tets[:, 0]]),
        points[tets[:, 3]] - points[tets[:, 0]],
    )
    neg = d < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return points, tets, tags


def boundary_triangles(tets):
    """Faces that belong to exactly one tet, oriented outward (for a positively oriented mesh)."""
    faces = np.concatenate(
        [tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]]
    )
    key = np.sort(faces, axis=1)
    _, idx, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[idx[counts == 1]]


def quadratic_cells(points, tets):
    """Adds edge midpoints: returns (points10, cells10) in FElupe's tetra10 node order
    (corners 0–3, then edges 01, 12, 20, 03, 13, 23)."""
    edges = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]
    pairs = np.concatenate([np.sort(tets[:, e], axis=1) for e in edges])
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    mids = 0.5 * (points[uniq[:, 0]] + points[uniq[:, 1]])
    n = len(points)
    cells = np.hstack([tets, (n + inv.reshape(len(edges), -1).T)])
    return np.vstack([points, mids]), cells


def tet10_shape(lam):
    """Quadratic tet shape functions at barycentric coordinates lam (k,4) → (k,10), node order of
    `quadratic_cells`."""
    l0, l1, l2, l3 = lam.T
    return np.stack(
        [
            l0 * (2 * l0 - 1), l1 * (2 * l1 - 1), l2 * (2 * l2 - 1), l3 * (2 * l3 - 1),
            4 * l0 * l1, 4 * l1 * l2, 4 * l2 * l0, 4 * l0 * l3, 4 * l1 * l3, 4 * l2 * l3,
        ],
        axis=1,
    )


def locate(points, tets, xs):
    """For each point of xs (k,3): (containing tet index, barycentric coordinates (4,)), choosing
    the tet with the largest minimum barycentric coordinate (points on the surface lie on a face)."""
    a = points[tets[:, 0]]
    m = np.stack([points[tets[:, i]] - a for i in (1, 2, 3)], axis=2)  # (t,3,3) columns
    minv = np.linalg.inv(m)
    cells, lams = [], []
    for x in xs:
        l123 = np.einsum("tij,tj->ti", minv, x - a)
        lam = np.hstack([1 - l123.sum(1, keepdims=True), l123])
        best = int(np.argmax(lam.min(1)))
        if lam[best].min() < -1e-6:
            raise ValueError(f"marker at {x} lies outside the mesh")
        cells.append(best)
        lams.append(lam[best])
    return np.array(cells), np.array(lams)
