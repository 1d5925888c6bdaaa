"""Regenerate ``proprio/robots/iiwa14_{identified,nominal}.yaml`` from ``../shared/reference/iiwa14_parameters.yaml``.

Provenance script: the shipped YAML files are its output, so every number in them can be traced. Run
``python scripts/make_iiwa_descriptions.py [REFERENCE_YAML]``.

* Kinematics, limits: Table 2.3 of the thesis (position/velocity, stated in degrees, kept in degrees in the YAML and
  converted by the loader); efforts from Drake's URDF. Acceleration limits are not published by KUKA: we assume
  the values below (documented as such).
* ``iiwa14_nominal``: Drake's round-number CAD set (``drake_models``) in Drake's frames, no friction.
* ``iiwa14_identified``: the ETHZ/Stürz identified set with viscous + Coulomb friction, in the ETHZ frames. Its
  flange gets rpy (0, 0, π) so that the flange frame coincides with Drake's (the two chains' link origins agree for
  every q; only frame orientations differ). Three link inertias of that set are not physically valid (principal
  moments violate the triangle inequality: links 2, 4, 7); they are projected to the closest valid tensor by
  clamping the largest principal moment to 0.99 × the sum of the other two, keeping the principal axes.
* Collision primitives: one cylinder per link along the segment from the link origin to the next joint origin (or
  to the flange), radii by link; a base cylinder. Coarse, for self-collision screening in trajectory generation
  (``proprio.systems.collision``). Link 5's cylinder stops ``DISTAL_CLEARANCE`` short of the joint-6 axis: the
  real wrist housing there is a narrow fork, and with the full segment the coarse cylinders of links 5 and 7
  would overlap for |q6| > 110° although the real iiwa moves its wrist through the whole ±120° range. With these
  primitives every single joint swept over its full range from q = 0 is free of self-collision
  (``tests/test_rfma.py``), while folding the arm back onto itself is caught.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
POS_DEG = [170, 120, 170, 120, 170, 120, 175]                      # Table 2.3
VEL_DEG_S = [85, 85, 100, 75, 130, 135, 135]                        # Table 2.3
ACC_RAD_S2 = [8.0, 8.0, 10.0, 10.0, 15.0, 15.0, 20.0]               # assumed (not published by KUKA)
RADII = [0.07, 0.07, 0.065, 0.065, 0.06, 0.055, 0.045]
DISTAL_CLEARANCE = [0.0, 0.0, 0.0, 0.0, 0.10, 0.0, 0.0]           # m cut from each cylinder's distal end
FLANGE_Z = 0.045


def _rpy_aligning_z(d: np.ndarray) -> list[float]:
    z = d / np.linalg.norm(d)
    if abs(z[2]) > 1 - 1e-12:
        return [0.0, 0.0, 0.0] if z[2] > 0 else [math.pi, 0.0, 0.0]
    # rotation about x then y: R = Ry(p) Rx(r) maps z to (sin p cos r, -sin r, cos p cos r)
    r = math.asin(-z[1])
    p = math.atan2(z[0], z[2])
    return [r, p, 0.0]


def _projected_inertia(vals: list[float]) -> tuple[list[float], bool]:
    ixx, iyy, izz, ixy, ixz, iyz = vals
    i = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    w, v = np.linalg.eigh(i)
    if w[0] + w[1] >= w[2]:
        return vals, False
    w[2] = 0.99 * (w[0] + w[1])
    j = v @ np.diag(w) @ v.T
    return [float(x) for x in (j[0, 0], j[1, 1], j[2, 2], j[0, 1], j[0, 2], j[1, 2])], True


def _description(ref: dict, set_name: str, name: str, provenance: str, ee_rpy: list[float], friction: bool) -> dict:
    s = ref[set_name]
    keys = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
    origins = [s["joint_origins"][f"joint_{i}"] for i in range(1, 8)]
    seg_ends = [np.array(origins[i + 1]["xyz"], dtype=float) for i in range(6)] + [np.array([0, 0, FLANGE_Z])]
    links, notes = [], []
    for i in range(1, 8):
        lk = s["links"][f"link_{i}"]
        inertia, changed = _projected_inertia([float(x) for x in lk["inertia"]])
        if changed:
            notes.append(f"link_{i} inertia projected from {lk['inertia']}")
        d = seg_ends[i - 1] * (1.0 - DISTAL_CLEARANCE[i - 1] / np.linalg.norm(seg_ends[i - 1]))
        links.append({
            "name": f"iiwa_link_{i}", "mass": float(lk["mass"]), "com_xyz": [float(x) for x in lk["com"]],
            "com_rpy": [0.0, 0.0, 0.0], "inertia_com": dict(zip(keys, inertia)),
            "collision": [{"shape": "cylinder", "radius": RADII[i - 1], "length": float(np.linalg.norm(d)),
                           "xyz": (d / 2).tolist(), "rpy": _rpy_aligning_z(d)}],
        })
    base = s["links"]["link_0"]
    joints = []
    parent = "iiwa_link_0"
    for i, o in enumerate(origins):
        joints.append({
            "name": f"iiwa_joint_{i + 1}", "parent": parent, "child": f"iiwa_link_{i + 1}",
            "origin_xyz": [float(x) for x in o["xyz"]], "origin_rpy": [float(x) for x in o["rpy"]],
            "axis": [0.0, 0.0, 1.0],
            "limits": {"lower_deg": -POS_DEG[i], "upper_deg": POS_DEG[i], "velocity_deg": VEL_DEG_S[i],
                       "effort": float(ref["drake_models"]["effort_limit_Nm"][i]), "acceleration": ACC_RAD_S2[i]},
        })
        parent = f"iiwa_link_{i + 1}"
    out = {
        "format": "proprio-robot/v1", "name": name,
        "provenance": provenance + (" Inertia projections: " + "; ".join(notes) + "." if notes else ""),
        "gravity_world": [0.0, 0.0, -9.81],
        "base": {"world_to_base_link": {"xyz": [0.0, 0.0, 0.0], "rpy": [0.0, 0.0, 0.0]},
                 "base_link": {"name": "iiwa_link_0", "mass": float(base["mass"]),
                               "com_xyz": [float(x) for x in base["com"]], "com_rpy": [0.0, 0.0, 0.0],
                               "inertia_com": dict(zip(keys, (float(x) for x in base["inertia"]))),
                               "collision": [{"shape": "cylinder", "radius": 0.09, "length": 0.1575,
                                              "xyz": [0.0, 0.0, 0.07875], "rpy": [0.0, 0.0, 0.0]}]}},
        "joints": joints, "links": links,
        "end_effector": {"name": "flange", "parent": "iiwa_link_7", "xyz": [0.0, 0.0, FLANGE_Z], "rpy": ee_rpy},
    }
    if friction:
        out["friction"] = {"viscous": [float(x) for x in s["friction_viscous_Nms_per_rad"]],
                           "coulomb": [float(x) for x in s["friction_coulomb_Nm"]]}
    return out


def main(reference: Path) -> None:
    ref = yaml.safe_load(reference.read_text())
    common = ("Limits: thesis Table 2.3 (deg, deg/s); efforts from Drake's iiwa14 URDF; accelerations assumed "
              f"{ACC_RAD_S2} rad/s^2. Generated by scripts/make_iiwa_descriptions.py from "
              "../shared/reference/iiwa14_parameters.yaml.")
    nominal = _description(ref, "drake_models", "iiwa14_nominal",
                           "Nominal CAD model: Drake's iiwa14 round-number inertials (" +
                           " ".join(ref["drake_models"]["provenance"].split()) + ") No friction. " + common,
                           [0.0, 0.0, 0.0], friction=False)
    identified = _description(ref, "ethz_identified", "iiwa14_identified",
                              "The robot the twin treats as real: ETHZ/Stuerz identified iiwa14 set with friction (" +
                              " ".join(ref["ethz_identified"]["provenance"].split()) + ") Flange rpy (0,0,pi) aligns "
                              "the flange with Drake's frame. " + common, [0.0, 0.0, math.pi], friction=True)
    for d in (nominal, identified):
        path = ROOT / "proprio" / "robots" / f"{d['name']}.yaml"
        path.write_text(f"# {d['name']} -- generated by scripts/make_iiwa_descriptions.py; see 'provenance'.\n" +
                        yaml.safe_dump(d, sort_keys=False, width=120, default_flow_style=None))
        print("wrote", path)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared" / "reference" / "iiwa14_parameters.yaml")
