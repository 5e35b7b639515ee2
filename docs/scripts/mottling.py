"""mottling.py PRESET [KEY=VALUE ...]: low-frequency mottling of qhm's global term.

Renders the built-in sphere of a homogeneous preset (64 x 64, one
directional light from the front) at seeds 1-3 and prints, per channel, the
8 x 8-block relative RMSE of each against one render with 4x the surface
samples (120,000) and 16 spp. KEY=VALUE lines go into both renders'
[render] table (e.g. near_field=0). The qhm binary is $QHM (default
target/release/qhm); reading EXR needs the mitsuba package.
"""
import os
import subprocess
import sys
import tempfile

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")
QHM = os.environ.get("QHM", "target/release/qhm")
SCENE = """[camera]
eye = [0, -150, 20]
target = [0, 0, 20]
up = [0, 0, 1]
fov_deg = 18
[[lights]]
kind = "directional"
direction = [-0.5, -1, 0.6]
irradiance = [1, 1, 1]
[env]
builtin = "none"
[render]
width = 64
height = 64
"""


def render(preset, keys, work, name):
    scene = os.path.join(work, name + ".toml")
    out = os.path.join(work, name + ".exr")
    with open(scene, "w") as f:
        f.write(SCENE + "".join(k + "\n" for k in keys))
    subprocess.run([QHM, "render", "--model", "builtin:" + preset, "--builtin", "sphere",
                    "--scene", scene, "-o", out, "--force"], check=True, capture_output=True)
    return np.array(mi.Bitmap(out))[..., :3]


def main():
    preset, extra = sys.argv[1], [a.replace("=", " = ", 1) for a in sys.argv[2:]]
    with tempfile.TemporaryDirectory() as work:
        ref = render(preset, extra + ["surface_samples = 120000", "spp = 16"], work, "ref")
        hit = ref.sum(-1) > 0
        inner = hit.copy()  # pixels whose 4-neighbours see the sphere too
        inner[1:] &= hit[:-1]; inner[:-1] &= hit[1:]; inner[:, 1:] &= hit[:, :-1]; inner[:, :-1] &= hit[:, 1:]
        for seed in (1, 2, 3):
            img = render(preset, extra + [f"seed = {seed}"], work, f"s{seed}")
            errs = [img[y:y + 8, x:x + 8].reshape(-1, 3).mean(0) / ref[y:y + 8, x:x + 8].reshape(-1, 3).mean(0) - 1
                    for y in range(0, 64, 8) for x in range(0, 64, 8) if inner[y:y + 8, x:x + 8].all()]
            rmse = np.sqrt((np.array(errs) ** 2).mean(0))
            print(f"{preset} seed {seed}: " + " / ".join(f"{100 * v:.2f} %" for v in rmse))


if __name__ == "__main__":
    main()
