import json, math, numpy as np, mitsuba as mi
mi.set_variant('scalar_rgb')
# smooth env map in qhm's convention (z up, u = atan2(y,x)/2pi, v = acos z / pi)
W, H = 128, 64
img = np.zeros((H, W, 3), np.float32)
for j in range(H):
    t = (j + 0.5) / H * math.pi
    for i in range(W):
        p = (i + 0.5) / W * 2 * math.pi
        d = np.array([math.sin(t)*math.cos(p), math.sin(t)*math.sin(p), math.cos(t)])
        sky = 0.15 + 0.6 * (0.5 + 0.5 * d[2]) ** 2
        warm = 0.8 * max(0.0, d @ np.array([-0.6, -0.5, 0.62])) ** 6
        img[j, i] = [sky + warm, sky * 0.95 + 0.8 * warm, sky * 1.1 + 0.5 * warm]
mi.Bitmap(img).write('ref/env.exr')
base = {"width": 64, "height": 64, "eye": [0, -150, 20], "target": [0, 0, 20], "fov_deg": 18,
        "sphere": {"center": [0, 0, 20], "radius": 20}}
lights = {"front": [-0.5, -1, 0.6], "side": [-1, 0, 0.05], "back": [0.45, 1, 0.3]}
for mat in ["skin1", "apple", "marble", "ketchup"]:
    for k, l in lights.items():
        s = dict(base, name=mat, sun={"to_light": l, "half_angle_deg": 8, "irradiance": 1.0})
        json.dump(s, open(f'ref/{mat}-{k}.json', 'w'))
    s = dict(base, name=mat, env={"file": "ref/env.exr", "scale": 1.0})
    json.dump(s, open(f'ref/{mat}-env.json', 'w'))
