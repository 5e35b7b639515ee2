#!/usr/bin/env python3
"""Loads `qhm render --export-mitsuba` files in Mitsuba 3 and checks what it read.

Usage: mitsuba_load.py CASES.json [--variant scalar_rgb]

CASES.json is a list of cases:
  {"file": "skin1.xml", "name": "skin1", "expect": "load",
   "sigma_t": [r, g, b], "albedo": [r, g, b], "eta": 1.3}
      the file must load as printed; included in a small scene (a sphere
      with the file's BSDF and interior medium, an emitter, a camera) it must
      give the medium an effective sigma_t (scale * value, per scene unit),
      sigma_s = albedo * sigma_t and the BSDF's eta as given (float32
      precision), and render a tiny image with finite values;
  {"file": "old.xml", "expect": "refuse"}
      Mitsuba must refuse to load the file because of its medium.

Driven by host/tests/export_interop.rs; exits non-zero if any case fails.
"""

import json
import math
import os
import sys
import tempfile

import mitsuba as mi

RTOL = 2e-6  # float32 parsing and one multiply by scale


def floats(x):
    """Python floats from a Mitsuba value (scalar variants give floats, JIT
    variants arrays of width 1)."""
    try:
        items = list(x)
    except TypeError:
        items = [x]
    out = []
    for v in items:
        try:
            out.append(float(v))
        except TypeError:
            out.append(float(v[0]))
    return out


def close(got, want):
    return all(math.isclose(g, w, rel_tol=RTOL, abs_tol=0.0) for g, w in zip(got, want))


def wrapper_scene(path, name):
    """A minimal scene that includes the exported file and uses its objects."""
    return f"""<scene version="3.0.0">
    <include filename="{path}"/>
    <integrator type="volpath"><integer name="max_depth" value="16"/></integrator>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    </sensor>
    <emitter type="constant"/>
    <shape type="sphere">
        <ref id="{name}-bsdf"/>
        <ref name="interior" id="{name}-medium"/>
    </shape>
</scene>"""


def check_load(case):
    path = os.path.abspath(case["file"])
    name = case["name"]
    mi.load_file(path)  # exactly what was printed, on its own
    with tempfile.TemporaryDirectory() as tmp:
        scene_path = os.path.join(tmp, "scene.xml")
        with open(scene_path, "w") as f:
            f.write(wrapper_scene(path, name))
        scene = mi.load_file(scene_path)
    shape = scene.shapes()[0]
    medium = shape.interior_medium()
    if medium is None:
        return "the sphere has no interior medium"
    eta = floats(mi.traverse(shape.bsdf())["eta"])
    if not close(eta, [case["eta"]]):
        return f"eta {eta} != {case['eta']}"
    mei = mi.MediumInteraction3f()
    mei.p = mi.Point3f(0, 0, 0)
    mei.t = 0.0
    sigma_s, _, sigma_t = medium.get_scattering_coefficients(mei)
    sigma_t, sigma_s = floats(sigma_t), floats(sigma_s)
    if not close(sigma_t, case["sigma_t"]):
        return f"sigma_t {sigma_t} != {case['sigma_t']}"
    want_s = [a * t for a, t in zip(case["albedo"], case["sigma_t"])]
    if not close(sigma_s, want_s):
        return f"sigma_s {sigma_s} != albedo * sigma_t {want_s}"
    image = mi.render(scene)
    values = floats(mi.TensorXf(image).array)
    if not values or not all(math.isfinite(v) and v >= 0 for v in values):
        return "the tiny render has non-finite or negative values"
    return None


def check_refuse(case):
    try:
        mi.load_file(os.path.abspath(case["file"]))
    except Exception as e:  # Mitsuba raises RuntimeError with the parser's message
        if "medium" in str(e):
            return None
        return f"refused, but not because of the medium: {e}"
    return "loaded, but Mitsuba was expected to refuse it"


def main(argv):
    variant = "scalar_rgb"
    args = list(argv[1:])
    if "--variant" in args:
        i = args.index("--variant")
        variant = args[i + 1]
        del args[i : i + 2]
    if len(args) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    mi.set_variant(variant)
    mi.set_log_level(mi.LogLevel.Warn)
    with open(args[0]) as f:
        cases = json.load(f)
    failed = 0
    for case in cases:
        check = check_load if case["expect"] == "load" else check_refuse
        try:
            why = check(case)
        except Exception as e:
            why = f"{type(e).__name__}: {e}"
        label = f"{case['expect']} {case['file']}"
        if why is None:
            print(f"ok   {label}")
        else:
            failed += 1
            print(f"FAIL {label}: {why}")
    print(f"mitsuba {mi.__version__} ({variant}): {len(cases) - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
