"""Writes one raw session (docs/session-format.md, length unit mm) with its truth/ folder."""
import os
import shutil

import numpy as np

from . import rig


def fmt(x, d=5):
    return f"{x:.{d}f}"


def write_session(out_dir, case, sim, mesh_lin, marker_ids, versions):
    rng = np.random.default_rng(case["seed"])
    tmp = out_dir.rstrip("/") + ".tmp"
    if os.path.exists(tmp):
        shutil.rmtree(tmp)
    for d in ("rig", "template", "detections", "truth"):
        os.makedirs(os.path.join(tmp, d))

    def w(rel, text):
        with open(os.path.join(tmp, rel), "w") as f:
            f.write(text)

    probe = case["probe"]
    axis = sim["axis"]
    nf = len(sim["frames"])
    t0 = 0.6 + rng.uniform(0, 0.3)
    t_frames = t0 + np.array([fr["t"] for fr in sim["frames"]])
    shaft = np.stack([[tip - d * axis for d in probe["shaft_markers_mm"]] for tip in sim["tips"]])
    centre = np.array([*(np.array(case["geometry"]["size_mm"][:2]) if case["geometry"]["shape"] == "block"
                         else 2 * np.array([case["geometry"]["size_mm"][0]] * 2)) / 2, 45.0])
    cams = rig.make_cameras(rng, centre)
    sim = dict(sim, probe=probe)

    # session.toml
    files = [
        'cameras = "rig/cameras.toml"', 'markers = "template/markers.csv"', 'detections = "detections"',
        'trigger = "trigger.csv"', 'fsr = "rig/fsr.toml"', 'fsr_samples = "fsr.csv"', 'probe = "rig/probe.toml"',
        'surface = "template/surface.obj"', 'volume = "template/volume.msh"',
    ]
    w("session.toml", "\n".join([
        'format = "softcap-session/1"', f'name = "{case["name"]}"', 'kind = "probe"', 'length_unit = "mm"', "",
        "[files]", *files, "", "[world]", "gravity = [0.0, 0.0, -9.81]", "",
        "[support]", "plane_normal = [0.0, 0.0, 1.0]", "plane_offset = 0.0", "tolerance = 0.5", "",
        "[object]", f"density_kg_m3 = {case['density_kg_m3']}",
        f'notes = "third-party truth suite (FElupe): {case["name"]}"', "",
    ]))

    # rig
    t = []
    for c in cams:
        R = c["R"]
        t += [
            "[[camera]]", f'id = "{c["id"]}"', f'width = {c["width"]}', f'height = {c["height"]}',
            f'fx = {c["fx"]:.6f}', f'fy = {c["fy"]:.6f}', f'cx = {c["cx"]:.6f}', f'cy = {c["cy"]:.6f}',
            f'k1 = {c["k1"]:.9g}', f'k2 = {c["k2"]:.9g}', f'p1 = {c["p1"]:.9g}', f'p2 = {c["p2"]:.9g}', "k3 = 0.0",
            "rotation = [" + ", ".join(f"{v:.15f}" for v in R.ravel()) + "]",
            "translation = [" + ", ".join(f"{v:.9f}" for v in c["t"]) + "]", "",
        ]
    w("rig/cameras.toml", "\n".join(t))
    p = [f'tip = "disk"', f'radius = {probe["radius_mm"]:.3f}']
    for i, (d, col) in enumerate(zip(probe["shaft_markers_mm"], probe["shaft_colors"])):
        p += ["", "[[shaft_marker]]", f'id = "shaft{i}"', f"distance_from_tip = {d:.3f}", f'color = "{col}"']
    w("rig/probe.toml", "\n".join(p) + "\n")

    axial = -(sim["forces"] @ axis) * -1.0  # force on the object along the pushing axis (>0 pushing)
    axial = sim["forces"] @ axis
    fsr = {"supply_v": 5.0, "divider_ohm": 10000.0, "k_ohm": 9300.0 * rng.uniform(0.9, 1.1),
           "n": rng.uniform(0.82, 0.95), "r_max_ohm": 3e7, "rate_hz": 500.0, "noise_v": 0.002,
           "adc_bits": 12, "exposure_s": 0.006, "trigger_high_v": 3.3}
    f_max = max(float(axial.max()), 1e-3) * 1.3
    cal = rig.calibration(rng, fsr, f_max)
    w("rig/fsr.toml", "supply_v = 5.0\ndivider_ohm = 10000.0\n"
      "# calibration from known weights: force (N) against measured voltage (V)\ncalibration = ["
      + ", ".join(f"[{f:.5f}, {v:.5f}]" for f, v in cal) + "]\n")
    clock = case.get("clock") or {"offset_s": float(rng.uniform(1.0, 3.0)), "drift": float(rng.uniform(-5e-5, 5e-5))}
    t_daq, volt, trig, sensed = rig.daq(rng, t_frames, np.maximum(axial, 0.0), fsr, clock, case["effects"])
    rows = ["t_daq_s,voltage_v" + (",trigger_v" if trig is not None else "")]
    for i in range(len(t_daq)):
        r = f"{t_daq[i]:.4f},{volt[i]:.5f}"
        if trig is not None:
            r += f",{trig[i]:.3f}"
        rows.append(r)
    w("fsr.csv", "\n".join(rows) + "\n")
    # what the FSR element responded to, against the true axial force, at the frames' DAQ times
    sensed_at = np.interp(clock["offset_s"] + (1 + clock["drift"]) * t_frames, t_daq, sensed)
    sim = dict(sim, sensor_rms_n=float(np.sqrt(np.mean((sensed_at - np.maximum(axial, 0.0)) ** 2))),
               peak_axial_n=float(axial.max()))
    w("trigger.csv", "frame,t_camera_s\n" + "".join(f"{k},{t:.6f}\n" for k, t in enumerate(t_frames)))

    # template
    tm = sim["template_markers"]
    w("template/markers.csv", "id,x,y,z,color\n" + "".join(
        f"{mid},{fmt(x[0])},{fmt(x[1])},{fmt(x[2])},blue\n" for mid, x in zip(marker_ids, tm)))
    write_msh(os.path.join(tmp, "template/volume.msh"), *mesh_lin)
    write_obj(os.path.join(tmp, "template/surface.obj"), *mesh_lin)

    # detections
    noise = {"px": 0.2, "dropout": 0.015, "random_blob": 0.02}
    det = rig.detections(rng, cams, sim, shaft, probe["shaft_colors"], "blue", noise)
    for cid, rr in det.items():
        w(f"detections/{cid}.csv", "frame,u,v,color\n" + "".join(f"{f},{u:.3f},{v:.3f},{c}\n" for f, u, v, c in rr))

    # truth
    lines = ["frame,id,x,y,z"]
    for f in range(nf):
        for mid, x in zip(marker_ids, sim["markers"][f]):
            lines.append(f"{f},{mid},{fmt(x[0])},{fmt(x[1])},{fmt(x[2])}")
        for i in range(2):
            x = shaft[f, i]
            lines.append(f"{f},shaft{i},{fmt(x[0])},{fmt(x[1])},{fmt(x[2])}")
    w("truth/markers.csv", "\n".join(lines) + "\n")
    w("truth/probe.csv", "frame,t_camera_s,fx,fy,fz,tip_x,tip_y,tip_z\n" + "".join(
        f"{f},{t_frames[f]:.6f},{sim['forces'][f][0]:.6f},{sim['forces'][f][1]:.6f},{sim['forces'][f][2]:.6f},"
        f"{fmt(sim['tips'][f][0])},{fmt(sim['tips'][f][1])},{fmt(sim['tips'][f][2])}\n" for f in range(nf)))
    w("truth/clock.toml", f"# t_daq = offset_s + (1 + drift) * t_camera\noffset_s = {clock['offset_s']:.6f}\ndrift = {clock['drift']:.9f}\n")
    w("truth/README.md", readme(case, sim, clock, fsr, versions, len(mesh_lin[1]), len(marker_ids)))
    w("truth/case.toml", case_toml(case))
    if os.path.exists(out_dir):
        shutil.rmtree(out_dir)
    os.rename(tmp, out_dir)


def case_toml(case):
    return "\n".join([
        f'name = "{case["name"]}"',
        f'effect = "{case["effect"] or "none"}"',
        f'pair = "{case["pair"] or ""}"',
        f'description = "{case["description"]}"',
    ]) + "\n"


def readme(case, sim, clock, fsr, versions, n_tets, n_markers):
    g = case["geometry"]
    peak = np.abs(sim["forces"] @ sim["axis"]).max()
    eff = case["effect"] or "none (control)"
    return f"""# Truth of `{case['name']}` (third-party truth suite)

Effect switched on: **{eff}**.{f" Paired control: `{case['pair']}`." if case['pair'] else ""}

{case['description']}

- Solver: FElupe {versions['felupe']} (quadratic tetrahedra, tetra10, 4-point quadrature), a Newton loop
  written for this suite; mesh by gmsh {versions['gmsh']} ({n_tets} linear tets, midside nodes added
  for the solution; template/volume.msh holds the linear tets as seen in frame 0).
- Object: {g['shape']} {g['size_mm']} mm on the table (z = 0); support: {case['support']['kind']}.
- Material: {case['material']}.
- Probe: rigid flat disk, radius {case['probe']['radius_mm']} mm, sharp edge, axis {np.round(sim['axis'], 3).tolist()},
  contact: {case['probe'].get('friction', 'none')} friction; {'force-controlled (the depths of its position-controlled twin), the disk a solid with a side wall (penalty contact)' if case['protocol'].get('control') == 'force' else 'displacement-controlled'}.
- Protocol: {len(case['locations_mm'])} locations, depths {case['depths_mm']} mm; per location hover,
  ramp {case['protocol']['ramp']} frames, hold {case['protocol']['hold']}, unload {case['protocol']['unload']},
  release {case['protocol']['release']}; {case['protocol']['fps']} Hz, {len(sim['frames'])} frames; peak axial force {peak:.3f} N.
- Gravity in the simulation: {case['gravity_n_mm3'] or 'not applied'}.
- Sensors: FSR R = k F^-n (k = {fsr['k_ohm']:.1f} ohm, n = {fsr['n']:.3f}), divider 10 kOhm at 5 V, DAQ
  {fsr['rate_hz']} Hz, 2 mV noise, 12 bit; trigger line {'absent' if case['effects'].get('no_trigger') else '3.3 V during each 6 ms exposure'};
  sensor lag: {case['effects'].get('sensor_lag') or 'none'} (force the FSR element responds to minus the
  true axial force at the frames: RMS {sim['sensor_rms_n']:.4f} N = {100 * sim['sensor_rms_n'] / max(sim['peak_axial_n'], 1e-12):.1f} % of the peak).
- Clock: offset {clock['offset_s']:.6f} s, drift {clock['drift'] * 1e6:.2f} ppm.
- Detections: {n_markers} blue markers + 2 shaft markers, unlabeled, 0.2 px noise, 1.5 % dropouts,
  markers hidden by the probe disk and shaft removed; spurious blue blobs: one persistent speck per
  camera, blobs parked 3–7 px beside a marker's image for 1.5–4.5 s, 2 % random single blobs.

Files: markers.csv (frame,id,x,y,z mm, object and shaft markers), probe.csv (force BY the probe ON
the object, N, world; tip = disk centre, mm), clock.toml, case.toml.
"""


def write_msh(path, points, tets):
    """Gmsh 4.1 ASCII: one volume entity with the linear tets."""
    n, m = len(points), len(tets)
    lo, hi = points.min(0), points.max(0)
    out = ["$MeshFormat", "4.1 0 8", "$EndMeshFormat", "$Entities", "0 0 0 1",
           f"1 {lo[0]:.6f} {lo[1]:.6f} {lo[2]:.6f} {hi[0]:.6f} {hi[1]:.6f} {hi[2]:.6f} 0 0", "$EndEntities",
           "$Nodes", f"1 {n} 1 {n}", f"3 1 0 {n}"]
    out += [str(i + 1) for i in range(n)]
    out += [f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}" for p in points]
    out += ["$EndNodes", "$Elements", f"1 {m} 1 {m}", f"3 1 4 {m}"]
    out += [f"{k + 1} " + " ".join(str(v + 1) for v in t) for k, t in enumerate(tets)]
    out += ["$EndElements", ""]
    with open(path, "w") as f:
        f.write("\n".join(out))


def write_obj(path, points, tets):
    from .geometry import boundary_triangles
    tris = boundary_triangles(tets)
    used = np.unique(tris)
    idx = -np.ones(len(points), int)
    idx[used] = np.arange(len(used))
    with open(path, "w") as f:
        for p in points[used]:
            f.write(f"v {p[0]:.6f} {p[1]:.6f} {p[2]:.6f}\n")
        for t in idx[tris]:
            f.write(f"f {t[0] + 1} {t[1] + 1} {t[2] + 1}\n")
