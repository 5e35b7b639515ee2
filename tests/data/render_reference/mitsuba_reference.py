#!/usr/bin/env python3
"""Reference renders of qhm's comparison scenes with Mitsuba 3 (volpathmis).

Usage: mitsuba_reference.py MEDIUM.xml SCENE.json OUT.exr [--spp N] [--seed S] [--variant V]

MEDIUM.xml is `qhm render --model builtin:NAME --export-mitsuba MEDIUM.xml`
(ids NAME-bsdf and NAME-medium, NAME from the JSON), included as printed.
SCENE.json describes the scene as qhm's comparison builds it (mm, z up):

  {"name": "skin1", "width": 64, "height": 64,
   "eye": [x, y, z], "target": [x, y, z], "fov_deg": 18,
   "sphere": {"center": [0, 0, 20], "radius": 20}      (or "mesh": "file.ply")
   "sun": {"to_light": [x, y, z], "half_angle_deg": 6, "irradiance": 1.0},
   "env": {"file": "env.exr", "scale": 1.0}             (qhm's lat-long, z up)
  }

The sun is a distant disk emitter of half-angle alpha and radiance
E / (pi sin^2 alpha): a surface facing it receives irradiance E, as from
qhm's directional light of irradiance E. The env map is in qhm's convention
(u = atan2(y, x) / 2 pi, v = acos(z) / pi), turned into Mitsuba's frame.
Writes OUT.exr: linear RGB and alpha (coverage).
"""

import json
import math
import os
import sys
import tempfile

import mitsuba as mi


def main():
    args = sys.argv[1:]
    opts = {"--spp": "256", "--seed": "0", "--variant": "scalar_rgb"}
    pos = []
    i = 0
    while i < len(args):
        if args[i] in opts:
            opts[args[i]] = args[i + 1]
            i += 2
        else:
            pos.append(args[i])
            i += 1
    if len(pos) != 3:
        sys.exit(__doc__)
    medium_xml, scene_json, out = pos
    mi.set_variant(opts["--variant"])
    s = json.load(open(scene_json))
    name = s["name"]
    eye, tgt = s["eye"], s["target"]
    v = lambda p: ", ".join(str(x) for x in p)
    parts = []
    sun = s.get("sun")
    if sun:
        l = sun["to_light"]
        n = math.sqrt(sum(x * x for x in l))
        l = [x / n for x in l]
        a = math.radians(sun["half_angle_deg"])
        dist = 1.0e4
        rho = dist * math.tan(a)
        c = s.get("sphere", {}).get("center", tgt)
        p = [c[k] + dist * l[k] for k in range(3)]
        up = [0, 0, 1] if abs(l[2]) < 0.9 else [1, 0, 0]
        radiance = sun["irradiance"] / (math.pi * math.sin(a) ** 2)
        parts.append(
            f"""<shape type="disk">
        <transform name="to_world"><scale value="{rho}"/>
            <lookat origin="{v(p)}" target="{v(c)}" up="{v(up)}"/></transform>
        <emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter>
    </shape>"""
        )
    env = s.get("env")
    if env:
        # qhm: d = (sin t cos p, sin t sin p, cos t), u = p / 2pi, v = t / pi.
        # Mitsuba (local d): u = atan2(d.x, -d.z) / 2pi, v = acos(d.y) / pi,
        # so local x -> world y, local y -> world z, local z -> world -x.
        parts.append(
            f"""<emitter type="envmap">
        <string name="filename" value="{os.path.abspath(env['file'])}"/>
        <float name="scale" value="{env.get('scale', 1.0)}"/>
        <transform name="to_world"><matrix value="0 0 -1 0  1 0 0 0  0 1 0 0  0 0 0 1"/></transform>
    </emitter>"""
        )
    if "sphere" in s:
        c = s["sphere"]["center"]
        geo = f"""<shape type="sphere">
        <point name="center" x="{c[0]}" y="{c[1]}" z="{c[2]}"/>
        <float name="radius" value="{s['sphere']['radius']}"/>"""
    else:
        kind = s["mesh"].rsplit(".", 1)[1]
        geo = f"""<shape type="{kind}">
        <string name="filename" value="{os.path.abspath(s['mesh'])}"/>"""
    geo += f"""
        <ref id="{name}-bsdf"/><ref name="interior" id="{name}-medium"/>
    </shape>"""
    nl = "\n    "
    xml = f"""<scene version="3.0.0">
    <include filename="{os.path.abspath(medium_xml)}"/>
    <integrator type="volpathmis"><integer name="max_depth" value="-1"/>
        <integer name="rr_depth" value="100000"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="{s['fov_deg']}"/><string name="fov_axis" value="y"/>
        <transform name="to_world"><lookat origin="{v(eye)}" target="{v(tgt)}" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="{s['width']}"/>
            <integer name="height" value="{s['height']}"/>
            <string name="pixel_format" value="rgba"/><rfilter type="box"/></film>
        <sampler type="independent"><integer name="sample_count" value="{opts['--spp']}"/></sampler>
    </sensor>
    {geo}
    {nl.join(parts)}
</scene>
"""
    with tempfile.NamedTemporaryFile("w", suffix=".xml", delete=False) as f:
        f.write(xml)
        path = f.name
    try:
        scene = mi.load_file(path)
    finally:
        os.unlink(path)
    img = mi.render(scene, seed=int(opts["--seed"]))
    mi.Bitmap(img).write(out)


if __name__ == "__main__":
    main()
