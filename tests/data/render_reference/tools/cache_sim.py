"""cache_sim.py SIM.exr[,SIM2.exr] SCENE.toml MATERIAL MESH CASE: writes CASE.json in render_reference's format
from a `qhm sim render-object` reference (no mirror reflection to remove: the lights are delta lights).
With two references of other seeds, the cache holds their mean, and half their difference as each
block's noise. MESH is a file under render_reference or builtin:NAME."""
import sys, os, json, numpy as np
args = sys.argv[1:]; sys.argv = sys.argv[:1]
exec(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), 'compare.py')).read().split('def main():')[0])
sim, toml, material, mesh, case = args
seeds = [load(f)[..., :3] for f in sim.split(",")]
s = sum(seeds) / len(seeds)
e = eroded(s.sum(-1) > 0)
rows = ["".join("o" if e[y, x] else "." for x in range(e.shape[1])) for y in range(e.shape[0])]
blocks = []
for by in range(0, e.shape[0], 8):
    for bx in range(0, e.shape[1], 8):
        if e[by:by+8, bx:bx+8].all():
            means = [x[by:by+8, bx:bx+8].reshape(-1, 3).mean(0) for x in seeds]
            noise = np.abs(means[0] - means[1]) / 2 if len(means) == 2 else np.zeros(3)
            blocks.append([bx, by] + s[by:by+8, bx:bx+8].reshape(-1, 3).mean(0).tolist() + noise.tolist())
out = {"case": case, "material": material, "mesh": mesh, "scene_toml": open(toml).read(),
       "reference": "qhm sim render-object, " + ("512 spp, seed 1" if len(seeds) == 1 else "2 x 256 spp, seeds 1 and 2"),
       "pixels": rows, "mean": s[e].mean(0).tolist(), "terminator": None, "blocks": blocks}
json.dump(out, open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", f"{case}.json"), "w"), indent=0)
print(case, int(e.sum()), len(blocks))
