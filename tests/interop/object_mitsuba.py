#!/usr/bin/env python3
"""Renders a homogeneous object in Mitsuba 3 (volpathmis) for the
sim-light object cross-check (tests/tests/sim_object.rs).

Usage: object_mitsuba.py CASE.json

CASE.json:
  {"mesh": "obj.ply",                  # PLY with vertex normals, mm
   "camera": {"eye": [..], "target": [..], "up": [..], "fov_y_deg": 25},
   "width": 64, "height": 64,
   "spp": 256, "runs": 4, "seed": 1,   # runs independent renders of spp each
   "env": {"file": "env.exr"},         # qhm's lat-long convention (z up)
   "env_visible": false,
   "sigma_t": [r, g, b], "albedo": [r, g, b], "eta": 1.3,
   "variant": "scalar_rgb",
   "out": "prefix"}

Writes PREFIX.exr (mean of the runs), PREFIX.var.exr (variance of that
mean per pixel, from the spread of the runs) and PREFIX.json (seconds).
"""

import json
import sys
import time

import numpy as np
import mitsuba as mi


def main():
    case = json.load(open(sys.argv[1]))
    mi.set_variant(case.get("variant", "scalar_rgb"))
    from mitsuba import ScalarTransform4f as T

    cam = case["camera"]
    st = np.array(case["sigma_t"], dtype=float)
    scale = float(st.max())
    # qhm's lat-long map: u = phi / 2 pi (phi = atan2(y, x)), v = theta / pi
    # from +z. Mitsuba's envmap: local y up, u from atan2(x, -z). The
    # rotation maps Mitsuba's local frame onto qhm's world.
    env_to_world = T([[0, 0, -1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {
                "type": "volpathmis",
                "max_depth": -1,
                "hide_emitters": not case.get("env_visible", False),
            },
            "sensor": {
                "type": "perspective",
                "fov": cam["fov_y_deg"],
                "fov_axis": "y",
                "to_world": T().look_at(origin=cam["eye"], target=cam["target"], up=cam["up"]),
                "film": {
                    "type": "hdrfilm",
                    "width": case["width"],
                    "height": case["height"],
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "independent", "sample_count": case["spp"]},
            },
            "env": {
                "type": "envmap",
                "filename": case["env"]["file"],
                "to_world": env_to_world,
            },
            "object": {
                "type": "ply",
                "filename": case["mesh"],
                "bsdf": {"type": "dielectric", "int_ior": case["eta"], "ext_ior": 1.0},
                "interior": {
                    "type": "homogeneous",
                    "sigma_t": {"type": "rgb", "value": (st / scale).tolist()},
                    "scale": scale,
                    "albedo": {"type": "rgb", "value": case["albedo"]},
                    "phase": {"type": "isotropic"},
                },
            },
        }
    )
    runs = []
    t0 = time.time()
    for k in range(case["runs"]):
        img = mi.render(scene, seed=case["seed"] * 1000 + k)
        runs.append(np.array(img)[..., :3].astype(np.float64))
    secs = time.time() - t0
    runs = np.stack(runs)
    mean = runs.mean(0)
    var = runs.var(0, ddof=1) / len(runs)
    out = case["out"]
    mi.Bitmap(mean.astype(np.float32)).write(out + ".exr")
    mi.Bitmap(var.astype(np.float32)).write(out + ".var.exr")
    json.dump({"seconds": secs, "spp_total": case["spp"] * case["runs"]}, open(out + ".json", "w"))


if __name__ == "__main__":
    main()
