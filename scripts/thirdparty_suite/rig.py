"""The recording rig: pinhole cameras with Brown–Conrady distortion, unlabeled blob detections
with noise, dropouts, occlusion by the probe and spurious blobs; the FSR divider on the DAQ clock
with its trigger line. Written from docs/session-format.md alone."""
import numpy as np


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """World→camera rotation and translation for a camera at `eye` looking at `target`
    (camera +z forward, +y down in the image)."""
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ eye


def make_cameras(rng, centre, n=3, distance=330.0, elevation_deg=52.0, width=1024, height=768):
    cams = []
    az0 = rng.uniform(0, 360)
    for c in range(n):
        az = np.radians(az0 + 360.0 * c / n + rng.uniform(-12, 12))
        el = np.radians(elevation_deg + rng.uniform(-6, 6))
        eye = centre + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        R, t = look_at(eye, centre + rng.normal(0, 3, 3))
        f = rng.uniform(1050, 1150)
        cams.append({
            "id": f"cam{c}", "width": width, "height": height,
            "fx": f, "fy": f * rng.uniform(0.999, 1.001),
            "cx": (width - 1) / 2 + rng.normal(0, 3), "cy": (height - 1) / 2 + rng.normal(0, 3),
            "k1": rng.uniform(-0.08, -0.02), "k2": rng.uniform(0.0, 0.02),
            "p1": rng.normal(0, 2e-4), "p2": rng.normal(0, 2e-4), "k3": 0.0,
            "R": R, "t": t, "eye": eye,
        })
    return cams


def project(cam, X):
    """Pixel coordinates of world points X (k,3); also the camera-frame depth."""
    Xc = X @ cam["R"].T + cam["t"]
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    r2 = x * x + y * y
    radial = 1 + cam["k1"] * r2 + cam["k2"] * r2 ** 2 + cam["k3"] * r2 ** 3
    p1, p2 = cam["p1"], cam["p2"]
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([cam["fx"] * xd + cam["cx"], cam["fy"] * yd + cam["cy"]], axis=1), Xc[:, 2]


def occluded_by_probe(eye, X, tip, axis, radius, shaft_radius, shaft_length):
    """Whether the segment eye→X passes through the probe's disk or its shaft cylinder."""
    out = np.zeros(len(X), bool)
    for k, x in enumerate(X):
        d = x - eye
        denom = d @ axis
        if abs(denom) > 1e-12:
            s = ((tip - eye) @ axis) / denom
            if 0.0 < s < 1.0 - 1e-6 and np.linalg.norm(eye + s * d - tip) <= radius:
                out[k] = True
                continue
        # closest approach between the sight segment and the shaft segment
        a0, a1 = tip, tip - shaft_length * axis
        if segment_distance(eye, x, a0, a1) <= shaft_radius:
            out[k] = True
    return out


def segment_distance(p0, p1, q0, q1):
    u, v, w = p1 - p0, q1 - q0, p0 - q0
    a, b, c, d, e = u @ u, u @ v, v @ v, u @ w, v @ w
    den = a * c - b * b
    s = np.clip((b * e - c * d) / den, 0, 1) if den > 1e-12 else 0.0
    t = np.clip((a * s + e) / c if c > 0 else 0.0, 0, 1)
    s = np.clip((b * t - d) / a if a > 0 else 0.0, 0, 1)
    return np.linalg.norm(p0 + s * u - (q0 + t * v))


def detections(rng, cams, sim, shaft_pts, shaft_colors, obj_color, noise):
    """Unlabeled detections per camera: rows (frame, u, v, color)."""
    nf = len(sim["frames"])
    probe = sim["probe"]
    rows = {c["id"]: [] for c in cams}
    marker_px = {}
    for c in cams:
        # spurious blobs that persist: a background speck, and blobs parked beside a marker's
        # image for a few seconds (a reflection, a fibre), some of them in the marker's colour
        speck = np.array([rng.uniform(50, c["width"] - 50), rng.uniform(50, c["height"] - 50)])
        near = []
        t_end = 0
        while t_end < nf:
            start = t_end + int(rng.integers(10, 60))
            length = int(rng.integers(15, 45))
            near.append((start, start + length, int(rng.integers(sim["markers"].shape[1])),
                         rng.uniform(3.0, 7.0), rng.uniform(0, 2 * np.pi)))
            t_end = start + length
        for f in range(nf):
            X = sim["markers"][f]
            tip = sim["tips"][f]
            uv, z = project(c, X)
            hidden = occluded_by_probe(c["eye"], X, tip, sim["axis"], probe["radius_mm"], probe["shaft_radius_mm"], probe["shaft_length_mm"])
            frame_rows = []
            for k in range(len(X)):
                if hidden[k] or rng.random() < noise["dropout"]:
                    continue
                frame_rows.append((uv[k] + rng.normal(0, noise["px"], 2), obj_color))
            suv, _ = project(c, shaft_pts[f])
            for k in range(len(suv)):
                if rng.random() < noise["dropout"]:
                    continue
                frame_rows.append((suv[k] + rng.normal(0, noise["px"], 2), shaft_colors[k]))
            frame_rows.append((speck + rng.normal(0, noise["px"], 2), obj_color))
            for (s0, s1, mk, dist, ang) in near:
                if s0 <= f < s1:
                    p = uv[mk] + dist * np.array([np.cos(ang), np.sin(ang)])
                    frame_rows.append((p + rng.normal(0, noise["px"], 2), obj_color))
            if rng.random() < noise["random_blob"]:
                frame_rows.append((np.array([rng.uniform(0, c["width"]), rng.uniform(0, c["height"])]), obj_color))
            for p, col in frame_rows:
                if 0 <= p[0] <= c["width"] - 1 and 0 <= p[1] <= c["height"] - 1:
                    rows[c["id"]].append((f, p[0], p[1], col))
        marker_px[c["id"]] = None
    return rows


def fsr_voltage(force_n, fsr):
    """Divider voltage of the FSR: R = k F^(−n), capped at r_max at no load."""
    f = np.maximum(force_n, 1e-12)
    R = np.minimum(fsr["k_ohm"] * f ** (-fsr["n"]), fsr["r_max_ohm"])
    return fsr["supply_v"] * fsr["divider_ohm"] / (fsr["divider_ohm"] + R)


def daq(rng, t_frames, axial_force, fsr, clock, effects):
    """DAQ samples: (t_daq, voltage, trigger or None, sensed force). The FSR sees the axial force
    (linear between frames); with sensor lag, a first-order lag then a play-type hysteresis."""
    rate = fsr["rate_hz"]
    off, drift = clock["offset_s"], clock["drift"]
    t0 = off + (1 + drift) * (t_frames[0] - 0.5)
    t1 = off + (1 + drift) * (t_frames[-1] + 0.5)
    t_daq = np.round(t0 * rate) / rate + np.arange(int((t1 - t0) * rate) + 1) / rate
    t_cam = (t_daq - off) / (1 + drift)
    force = np.interp(t_cam, t_frames, axial_force)
    sensed = force.copy()
    lag = effects.get("sensor_lag")
    if lag:
        a = 1 - np.exp(-1.0 / (rate * lag["tau_s"]))
        y = 0.0
        out = np.empty_like(force)
        play = 0.0
        for i, f in enumerate(force):
            y += a * (f - y)
            w = lag["play_fraction"] * y
            play = min(max(play, y - w), y + w)
            out[i] = play
        sensed = out
    v = fsr_voltage(sensed, fsr) + rng.normal(0, fsr["noise_v"], len(t_daq))
    lsb = fsr["supply_v"] / (2 ** fsr["adc_bits"] - 1)
    v = np.clip(np.round(v / lsb) * lsb, 0, fsr["supply_v"])
    trig = None
    if not effects.get("no_trigger"):
        # a trigger latency: the cameras expose that long after their pulse (a force synchronised
        # by the pulses reads the force that much before the frame: a small clock offset)
        latency = effects.get("trigger_latency_s", 0.0)
        high = np.zeros(len(t_daq), bool)
        for tf in t_frames:
            td = off + (1 + drift) * (tf - latency)
            high |= np.abs(t_daq - td) <= 0.5 * fsr["exposure_s"]
        trig = np.where(high, fsr["trigger_high_v"], 0.0) + rng.normal(0, 0.01, len(t_daq))
    return t_daq, v, trig, sensed


def calibration(rng, fsr, f_max):
    forces = np.array([0.0, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 0.85, 1.0, 1.2]) * f_max
    v = fsr_voltage(forces, fsr) * (1 + rng.normal(0, 0.004, len(forces)))
    v[0] = fsr_voltage(np.array([0.0]), fsr)[0]
    v = np.maximum.accumulate(v + np.arange(len(v)) * 1e-5)
    return np.stack([forces, v], axis=1)
