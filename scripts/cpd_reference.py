#!/usr/bin/env python3
"""Non-rigid Coherent Point Drift (Myronenko & Song 2010, pycpd) on the same clouds as
`softcap tissue track`: the reference the tracker is compared with (issue 29).

    scripts/cpd-reference SESSION CAPTURE.mcap TRACK.mcap OUT_DIR      # installs its own venv
    scripts/cpd-reference figure CAPTURE.mcap TRACK.mcap OUT.png       # tracked mesh over the cloud

CPD tracks sequentially like the tracker: frame t registers the surface samples carried to frame
t - 1 (a lattice of about SPACING on the template's boundary; pycpd solves an M x M system per
iteration, so M stays near a thousand) onto frame t's cloud (subsampled to at most MAX_POINTS
points), and the template's nodes move with CPD's displacement field v(z) = sum_m G(z, y_m) w_m. Its parameters (lambda = alpha,
beta, w) are chosen on the truth by a small grid over the first frames — the most favourable CPD
setting, not a tuned-against one. Writes

  OUT/cpd_nodes.csv   frame,node,x,y,z (m) for every template node (the tracker's node order)
  OUT/cpd.toml        pycpd version, parameters, the grid's scores, seconds per frame
and prints the surface-point error of both with the `track_eval` example, and draws
  OUT/cpd_vs_track.png   per-frame surface-point RMS of both against the truth.
"""
import os
import subprocess
import sys
import time

import numpy as np
import pycpd

MAX_POINTS = 2500
SPACING = 0.006


def read_csv(path):
    with open(path) as f:
        head = f.readline().strip().split(",")
        rows = [line.strip().split(",") for line in f if line.strip()]
    return head, rows


def frames_of(path, cols):
    head, rows = read_csv(path)
    ci = [head.index(c) for c in cols]
    fi = head.index("frame")
    out = {}
    for r in rows:
        out.setdefault(int(r[fi]), []).append([float(r[c]) for c in ci])
    return [np.array(out[k]) for k in sorted(out)]


def softcap(*args):
    exe = os.environ.get("SOFTCAP", "target/debug/softcap")
    subprocess.run([exe, *args], check=True)


def surface_samples(vertices, faces):
    """Vertices plus a barycentric lattice of about SPACING on every face (as the tracker)."""
    pts = [vertices[np.unique(faces)]]
    for a, b, c in faces:
        pa, pb, pc = vertices[a], vertices[b], vertices[c]
        n = int(np.ceil(max(np.linalg.norm(pa - pb), np.linalg.norm(pb - pc), np.linalg.norm(pc - pa)) / SPACING))
        for i in range(1, n):
            for j in range(1, n - i):
                k = n - i - j
                pts.append(((i * pa + j * pb + k * pc) / n)[None, :])
    return np.vstack(pts)


def displacement(z, y, beta, w):
    """CPD's displacement field at points z: v(z) = sum_m exp(-|z - y_m|^2 / (2 beta^2)) w_m
    (Myronenko & Song 2010 eq. 20, pycpd's kernel), y the registered set's starting positions."""
    d2 = ((z[:, None, :] - y[None, :, :]) ** 2).sum(axis=2)
    return np.exp(-d2 / (2.0 * beta**2)) @ w


def run_cpd(clouds, samples, nodes, alpha, beta, w, frames=None):
    y = samples.copy()
    x_nodes = nodes.copy()
    out = [x_nodes.copy()]
    rng = np.random.default_rng(0)
    seconds = []
    for k, cloud in enumerate(clouds[1:frames], start=1):
        if len(cloud) > MAX_POINTS:
            cloud = cloud[rng.choice(len(cloud), MAX_POINTS, replace=False)]
        t0 = time.perf_counter()
        reg = pycpd.DeformableRegistration(X=cloud, Y=y, alpha=alpha, beta=beta, w=w, max_iterations=60, tolerance=1e-6)
        y_new, _ = reg.register()
        x_nodes = x_nodes + displacement(x_nodes, y, reg.beta, reg.W)
        seconds.append(time.perf_counter() - t0)
        y = y_new
        out.append(x_nodes.copy())
    return out, seconds


def write_nodes(path, frames):
    with open(path, "w") as f:
        f.write("frame,node,x,y,z\n")
        for k, x in enumerate(frames):
            for i, p in enumerate(x):
                f.write(f"{k},{i},{p[0]:.9f},{p[1]:.9f},{p[2]:.9f}\n")


def rms_vs_truth(track_eval, session, nodes_csv):
    out = subprocess.run([track_eval, session, nodes_csv], check=True, capture_output=True, text=True).stdout
    row = [l for l in out.splitlines() if l.startswith(f"| {nodes_csv}")][0]
    return float(row.split("|")[3])


def main():
    session, capture, track, out = sys.argv[1:5]
    track_eval = os.environ.get("TRACK_EVAL", "target/debug/examples/track_eval")
    os.makedirs(out, exist_ok=True)
    points_csv = os.path.join(out, "points.csv")
    nodes_csv = os.path.join(out, "track_nodes.csv")
    softcap("inspect", "export", capture, "--what", "points", "-o", points_csv)
    softcap("inspect", "export", track, "--what", "nodes", "-o", nodes_csv)
    clouds = frames_of(points_csv, ["x", "y", "z"])
    tracked = frames_of(nodes_csv, ["x", "y", "z"])
    template = tracked[0]
    ply = os.path.join(out, "template.ply")
    softcap("inspect", "export", track, "--what", "volume", "-o", ply)
    with open(ply) as f:
        lines = f.read().splitlines()
    nv = int([l for l in lines if l.startswith("element vertex")][0].split()[-1])
    start = lines.index("end_header") + 1
    faces = np.array([[int(v) for v in l.split()[1:4]] for l in lines[start + nv:]])
    samples = surface_samples(template, faces)
    # the grid: CPD's best setting for the first 15 frames, judged on the truth
    grid = []
    probe = min(15, len(clouds))
    # CPD_PARAMS=alpha,beta_m skips the grid (e.g. another session's best setting)
    given = [float(v) for v in os.environ["CPD_PARAMS"].split(",")] if os.environ.get("CPD_PARAMS") else None
    for alpha in (given[0],) if given else (0.5, 2.0, 8.0):
        for beta in (given[1],) if given else (0.02, 0.05, 0.1):
            frames, _ = run_cpd(clouds, samples, template, alpha, beta, 0.1, probe)
            tmp = os.path.join(out, "grid_nodes.csv")
            write_nodes(tmp, frames)
            grid.append((rms_vs_truth(track_eval, session, tmp), alpha, beta))
            print(f"grid alpha {alpha} beta {beta}: {grid[-1][0]:.3f} mm", file=sys.stderr)
    best = min(grid)
    frames, seconds = run_cpd(clouds, samples, template, best[1], best[2], 0.1)
    cpd_csv = os.path.join(out, "cpd_nodes.csv")
    write_nodes(cpd_csv, frames)
    table = subprocess.run([track_eval, session, nodes_csv, cpd_csv], check=True, capture_output=True, text=True).stdout
    print(table)
    with open(os.path.join(out, "cpd.toml"), "w") as f:
        f.write("# written by scripts/cpd_reference.py; do not edit\n")
        f.write(f'pycpd = "{getattr(pycpd, "__version__", "2.0.0")}"\nnumpy = "{np.__version__}"\n')
        f.write(f"alpha = {best[1]}\nbeta_m = {best[2]}\nw = 0.1\nmax_points = {MAX_POINTS}\nsamples = {len(samples)}\n")
        f.write(f"seconds_per_frame = {np.mean(seconds):.3f}\n")
        f.write("grid = [" + ", ".join(f"[{a}, {b}, {r:.4f}]" for r, a, b in grid) + "]  # [alpha, beta_m, rms_mm of the first frames]\n")
        f.write('table = """\n' + table + '"""\n')
    plot(session, track_eval, nodes_csv, cpd_csv, out)


def plot(session, track_eval, nodes_csv, cpd_csv, out):
    """OUT/cpd_vs_track.png: per-frame surface-point RMS of both trackers against the truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = subprocess.run([track_eval, "--per-frame", session, nodes_csv, cpd_csv], check=True, capture_output=True, text=True).stdout
    lines = rows.strip().splitlines()
    data = np.array([[float(v) for v in l.split(",")] for l in lines[1:]])
    summary = subprocess.run([track_eval, session, nodes_csv, cpd_csv], check=True, capture_output=True, text=True).stdout
    rms = {l.split("|")[1].strip(): l.split("|")[3].strip() for l in summary.splitlines() if l.startswith("| ") and "RMS" not in l}
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(data[:, 0], data[:, 2], label=f"softcap tissue track (wang2015 §5): {rms[nodes_csv]} mm RMS")
    ax.plot(data[:, 0], data[:, 3], label=f"non-rigid CPD (pycpd): {rms[cpd_csv]} mm RMS")
    ax.plot(data[:, 0], data[:, 1], ":", color="gray", label=f"template floor: {rms['template floor']} mm RMS")
    ax.set_xlabel("frame (30 Hz)")
    ax.set_ylabel("surface-point RMS (mm)")
    ax.set_title(os.path.basename(os.path.normpath(session)))
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "cpd_vs_track.png"), dpi=120)


def figure(capture, track, out_png, frames=(0, 9, 12, 30)):
    """`figure CAPTURE TRACK OUT.png`: the tracked mesh's boundary edges over the frame's cloud,
    side view (x, z), for a few frames (docs/dynamic.md)."""
    import tempfile

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tmp = tempfile.mkdtemp()
    softcap("inspect", "export", capture, "--what", "points", "-o", os.path.join(tmp, "points.csv"))
    softcap("inspect", "export", track, "--what", "nodes", "-o", os.path.join(tmp, "nodes.csv"))
    softcap("inspect", "export", track, "--what", "volume", "-o", os.path.join(tmp, "t.ply"))
    clouds = frames_of(os.path.join(tmp, "points.csv"), ["x", "y", "z"])
    nodes = frames_of(os.path.join(tmp, "nodes.csv"), ["x", "y", "z"])
    with open(os.path.join(tmp, "t.ply")) as f:
        lines = f.read().splitlines()
    nv = int([l for l in lines if l.startswith("element vertex")][0].split()[-1])
    start = lines.index("end_header") + 1
    faces = [[int(v) for v in l.split()[1:4]] for l in lines[start + nv:]]
    edges = sorted({tuple(sorted((f[i], f[(i + 1) % 3]))) for f in faces for i in range(3)})
    frames = [k for k in frames if k < len(nodes)]
    fig, axes = plt.subplots(1, len(frames), figsize=(3.2 * len(frames), 2.6), sharey=True)
    for ax, k in zip(np.atleast_1d(axes), frames):
        c = clouds[k]
        ax.scatter(1e3 * c[:, 0], 1e3 * c[:, 2], s=0.2, color="0.6", rasterized=True)
        x = nodes[k]
        for a, b in edges:
            ax.plot(1e3 * x[[a, b], 0], 1e3 * x[[a, b], 2], color="tab:blue", lw=0.5)
        ax.set_title(f"frame {k}", fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_aspect("equal")
    np.atleast_1d(axes)[0].set_ylabel("z (mm)")
    fig.tight_layout()
    fig.savefig(out_png, dpi=130)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "figure":
        figure(*sys.argv[2:5])
    else:
        main()
