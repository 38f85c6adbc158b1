"""The suite: four controls, one case per catalog effect (inertia-damping excepted) and, for each
effect case, its paired control (same geometry, material and protocol without the effect).

Units: mm, N, MPa, s. Neo-Hooke μ = 0.017 MPa is E ≈ 50 kPa at ν ≈ 0.475 (bulk K = 20 μ)."""
import copy

MU = 0.017
BLOCK = {"shape": "block", "size_mm": [40.0, 40.0, 20.0], "h_top_mm": 3.6, "h_bottom_mm": 7.0}
PROTOCOL = {"fps": 10.0, "hover_mm": 4.0, "approach": 2, "ramp": 10, "hold": 12, "unload": 10, "release": 3}
LOCATIONS = [[13.0, 13.5], [27.0, 12.5], [20.5, 20.0], [12.5, 27.0], [27.5, 27.5], [20.0, 31.0]]
DEPTHS = [2.0, 2.3, 1.7, 2.5, 1.9, 2.2]
PROBE = {"radius_mm": 5.0, "shaft_radius_mm": 4.0, "shaft_length_mm": 150.0,
         "shaft_markers_mm": [60.0, 120.0], "shaft_colors": ["red", "yellow"], "friction": "none"}
NEO_HOOKE = {"kind": "neo-hooke", "mu": MU, "bulk": 20 * MU}

BASE = {
    "geometry": BLOCK,
    "material": NEO_HOOKE,
    "support": {"kind": "bonded"},
    "protocol": PROTOCOL,
    "locations_mm": LOCATIONS,
    "depths_mm": DEPTHS,
    "probe": PROBE,
    "markers": {"grid": 6, "margin_mm": 5.0, "jitter_mm": 0.7},
    "effects": {},
    "effect": None,
    "pair": None,
    "gravity_n_mm3": None,
    "density_kg_m3": 1050.0,
}


def case(name, seed, description, **over):
    c = copy.deepcopy(BASE)
    for k, v in over.items():
        c[k] = copy.deepcopy(v)
    c["name"] = name
    c["seed"] = seed
    c["description"] = description
    return c


def cases():
    tilt = [0.342, 0.0, -0.940]  # 20° from the vertical, in the x–z plane
    oblique = [0.2588, 0.0, -0.9659]  # 15° (support-slip: the bonded twin converges at 15°, not at 20°)
    # probe-friction's push: the tip also travels sideways, toward the shaft's lean (+x: the disk's
    # high rim leads, its buried low rim trails), so the stuck disk drags the surface
    oblique_path = {"ratio": 0.6, "dir": [1.0, 0.0, 0.0]}
    oblique_push = dict(PROTOCOL, slide=oblique_path)
    gravity_block = dict(BLOCK, size_mm=[40.0, 40.0, 28.0], h_bottom_mm=7.5)
    soft = {"kind": "neo-hooke", "mu": 0.0035, "bulk": 20 * 0.0035}
    j2 = {"kind": "j2", "E": 0.05, "nu": 0.45, "yield": 0.0045, "hardening": 0.004}
    out = [
        case("clean", 101, "Control: homogeneous nearly incompressible neo-Hooke block, bonded base."),
        case("stiff-inclusion", 102, "Control: a stiff sphere (radius 6 mm, 8x the shear modulus) inside the block.",
             material=dict(NEO_HOOKE, mu_inclusion=8 * MU), inclusion=[[20.0, 20.0, 9.0], 6.0]),
        case("strain-stiffening", 103, "Control: Yeoh material (C20 = 3 C10), strain stiffening under the punch edge.",
             material={"kind": "yeoh", "C10": MU / 2, "C20": 1.5 * MU, "C30": 0.0, "bulk": 20 * MU}),
        case("cylinder", 104, "Control: another geometry, a cylinder (radius 22 mm, height 18 mm), softer neo-Hooke.",
             geometry={"shape": "cylinder", "size_mm": [22.0, 18.0], "h_top_mm": 3.6, "h_bottom_mm": 7.0},
             material={"kind": "neo-hooke", "mu": 0.012, "bulk": 20 * 0.012},
             locations_mm=[[15.0, 16.0], [29.0, 16.5], [22.0, 22.5], [15.5, 29.0], [29.0, 28.5], [22.0, 33.0]],
             markers={"grid": 7, "margin_mm": 3.0, "jitter_mm": 0.7, "disc": True}),
        case("viscoelasticity", 201, "Effect viscoelasticity: neo-Hooke (the clean material) plus two finite-strain "
             "Maxwell branches (Shutov et al. 2013): mu_1 = 0.010 MPa, tau_1 = 0.3 s; mu_2 = 0.008 MPa, tau_2 = 2.0 s.",
             material={"kind": "viscoelastic", "mu": MU, "bulk": 20 * MU, "branches": [[0.010, 0.3], [0.008, 2.0]]},
             effect="viscoelasticity", pair="clean"),
        case("plasticity", 202, "Effect plasticity: J2 plasticity (small-strain kinematics, radial return), "
             "E = 50 kPa, nu = 0.45, yield 4.5 kPa, linear isotropic hardening 4 kPa.",
             material=j2, effect="plasticity", pair="plasticity-pair"),
        case("plasticity-pair", 203, "Paired control of plasticity: the same small-strain linear elastic material without yield.",
             material=dict(j2, **{"yield": None})),
        case("support-slip", 204, "Effect support-slip: the probe pushes obliquely (shaft tilted 15 degrees in the "
             "x-z plane, frictionless disk) and the base rests on a compliant interface (a soft mat): per area a "
             "tangential stiffness 1e-3 MPa/mm (1.6 N/mm over the base), smoothly capped at the Coulomb limit "
             "mu (p + rho g H), mu = 5 (reached only at the unloaded rim): the base slides with the push.",
             probe_axis=oblique, support={"kind": "friction", "mu": 5.0, "k_t": 1.0e-3, "p_weight": 2.1e-4},
             effect="support-slip", pair="support-slip-pair"),
        case("support-slip-pair", 212, "Paired control of support-slip: the same oblique probe (15 degrees), bonded base.",
             probe_axis=oblique),
        case("anisotropy", 205, "Effect anisotropy: HGO-like matrix (neo-Hooke mu = 0.017 MPa) with two fibre families "
             "at +-30 degrees to x in the top plane, k1 = 0.1 MPa, k2 = 4.",
             material={"kind": "hgo", "mu": MU, "bulk": 20 * MU, "k1": 0.1, "k2": 4.0,
                       "fibres": [[0.866, 0.5, 0.0], [0.866, -0.5, 0.0]]},
             effect="anisotropy", pair="clean"),
        case("gravity-preload", 206, "Effect gravity-preload: a soft tall block (mu = 3.5 kPa, 28 mm) sagged under its "
             "weight; the template is the sagged shape.",
             geometry=gravity_block, material=soft, gravity_n_mm3=[0.0, 0.0, -1.03e-5],
             depths_mm=[1.8, 2.1, 1.7, 2.2, 1.8, 2.0], effect="gravity-preload", pair="gravity-preload-pair"),
        case("gravity-preload-pair", 207, "Paired control of gravity-preload: the same soft tall block without gravity.",
             geometry=gravity_block, material=soft, depths_mm=[1.8, 2.1, 1.7, 2.2, 1.8, 2.0]),
        case("probe-friction", 208, "Effect probe-friction: shaft tilted 20 degrees from the vertical, pushed in "
             f"along an oblique path ({oblique_path['ratio']} mm sideways (+x) per mm of depth, back on the way out); "
             "the disk sticks to the surface where it touches (full friction) and drags it along.",
             probe_axis=tilt, probe=dict(PROBE, friction="stick"), protocol=oblique_push,
             effect="probe-friction", pair="probe-friction-pair"),
        case("probe-friction-pair", 209, "Paired control of probe-friction: the same tilted probe on the same oblique "
             "path, frictionless.",
             probe_axis=tilt, protocol=oblique_push),
        case("clock-offset", 210, "Effect clock-offset: no trigger line in fsr.csv; the DAQ clock runs 3.412 s ahead "
             "(drift 35 ppm). The physics is the clean case's.",
             effects={"no_trigger": True}, clock={"offset_s": 3.412, "drift": 3.5e-5},
             effect="clock-offset", pair="clean"),
        case("sensor-lag", 211, "Effect sensor-lag: the FSR follows the axial force through a first-order lag "
             "(tau = 0.15 s) and a play hysteresis of half-width 6 % of the lagged force. Physics of the clean case.",
             effects={"sensor_lag": {"tau_s": 0.15, "play_fraction": 0.06}}, effect="sensor-lag", pair="clean"),
    ]
    return out


def physics_key(c):
    """Cases with the same key share their finite element solution. The protocol's time step
    on the ramps (`ramp_step`, faster-ramps) changes the times of the same sequence of probe
    poses: it enters the solution only of a rate-dependent (viscoelastic) material."""
    import json
    keys = ["geometry", "material", "support", "protocol", "locations_mm", "depths_mm", "probe",
            "markers", "gravity_n_mm3", "inclusion", "probe_axis"]
    key = {k: c.get(k) for k in keys}
    if c["material"]["kind"] != "viscoelastic":
        key["protocol"] = {k: v for k, v in c["protocol"].items() if k != "ramp_step"}
    return json.dumps(key, sort_keys=True)
