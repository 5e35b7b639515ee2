"""A demo's lamp images, and its model rendered under the same light and
view, against `qhm sim render-object` of the same sample (statistics over
the fitted window, so for samples that are the same everywhere):

    QHM=target/release/qhm python3 tools/lamp_vs_truth.py DEMO_DIR SAMPLE IDX[,IDX...] [WORK_DIR]

IDX are indices of [[lamp]] in DEMO_DIR/capture/rectified/index.toml. For
each, a scene TOML looks down the lamp image's view from 300 mm at the
centre of a 60 x 60 x 30 mm box (box/box60x30.obj) under a directional
light along its light direction, irradiance 1; the truth is rendered at
128 spp (cached in WORK_DIR), the model with `qhm render`. Prints, per
channel, the lamp image's mean per unit irradiance over the truth's and
the render's over the truth's, and the share of the lamp image's texels
that are NaN (saturated in every exposure).
"""
import json, os, subprocess, sys, tomllib

import mitsuba as mi
import numpy as np

mi.set_variant('scalar_rgb')
Q = os.environ.get('QHM', 'qhm')
HERE = os.path.dirname(os.path.abspath(__file__))
MESH = os.path.join(HERE, '..', 'box', 'box60x30.obj')

demo, sample, idxs = sys.argv[1], sys.argv[2], [int(i) for i in sys.argv[3].split(',')]
work = sys.argv[4] if len(sys.argv) > 4 else 'lamp_vs_truth'
os.makedirs(work, exist_ok=True)
rect = os.path.join(demo, 'capture', 'rectified')
index = tomllib.load(open(os.path.join(rect, 'index.toml'), 'rb'))
i0, j0, w, h = json.load(open(os.path.join(demo, 'model', 'fit.json')))['window']
mean = lambda f: np.array(mi.Bitmap(f)).reshape(-1, 3).mean(0)
for i in idxs:
    lamp = index['lamp'][i]
    eye, light = 300 * np.array(lamp['view_dir']), lamp['light_dir']
    scene = os.path.join(work, f'{sample}-{i}.toml')
    with open(scene, 'w') as f:
        f.write(f"""[camera]
eye = [{eye[0]}, {eye[1]}, {eye[2]}]
target = [0, 0, 0]
fov_deg = 3.0
[[lights]]
kind = "directional"
direction = [{light[0]}, {light[1]}, {light[2]}]
irradiance = [1, 1, 1]
[env]
builtin = "none"
[render]
width = 64
height = 64
""")
    truth, render = scene[:-5] + '-truth.exr', scene[:-5] + '-model.exr'
    if not os.path.exists(truth):
        subprocess.run([Q, 'sim', 'render-object', '--sample', sample, '--mesh', MESH, '--scene', scene,
                        '--spp', '128', '--seed', '1', '-o', truth, '--quiet'], check=True)
    subprocess.run([Q, 'render', '--model', os.path.join(demo, 'model'), '--mesh', MESH, '--scene', scene,
                    '-o', render, '--quiet', '--force'], check=True)
    img = np.array(mi.Bitmap(os.path.join(rect, lamp['file'])))[j0:j0 + h, i0:i0 + w].reshape(-1, 3)
    lamp_mean = np.nanmean(img, axis=0) / np.array(lamp['irradiance'])
    t = mean(truth)
    print(f"lamp {i} (camera {lamp['camera']}, light z {light[2]:.2f}): "
          f"lamp image / truth {np.round(lamp_mean / t, 3)}, model / truth {np.round(mean(render) / t, 3)}, "
          f"NaN {np.round(np.mean(~np.isfinite(img), axis=0), 3)}")
