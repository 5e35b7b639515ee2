"""Writes tests/data/render_reference/CASE.json: the qhm scene TOML of the case and
the Mitsuba reference reduced to what the comparison needs (mirror reflection removed)."""
import json, sys, math, numpy as np, subprocess, os
sys.argv = [sys.argv[0]]
exec(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), 'compare.py')).read().split('def main():')[0])
import runpy
OUT = os.environ.get("OUT", os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
def toml_of(case):
    subprocess.run(["python3", os.path.join(os.path.dirname(os.path.abspath(__file__)), "runqhm.py"), f"ref/{case}.json", "/tmp/cache-dummy.exr", "--samples", "12000", "--spp", "4"],
                   env=dict(os.environ, VARIANT="--rd dipole"), check=True, capture_output=True)
    t = open("/tmp/cache-dummy.exr.toml").read()
    return t.replace(os.path.abspath("ref/env.exr"), "env.exr")
for case in sys.stdin.read().split():
    s = json.load(open(f"ref/{case}.json"))
    A = load(f"ref/{case}-s1.exr"); B = load(f"ref/{case}-s2.exr")
    alpha = np.minimum(A[..., 3], B[..., 3]); spec = specular(s)
    A = A[..., :3] - spec; B = B[..., :3] - spec
    n, m = compared(s, alpha)
    band = np.zeros_like(m)
    if "sun" in s:
        l = np.array(s["sun"]["to_light"], float); l /= np.linalg.norm(l); band = m & (np.abs(n @ l) < 0.25)
    rows = ["".join("t" if band[y, x] else ("o" if m[y, x] else ".") for x in range(s["width"])) for y in range(s["height"])]
    r = 0.5 * (A + B); nz = 0.5 * (A - B)
    blocks = []
    for by in range(0, s["height"], 8):
        for bx in range(0, s["width"], 8):
            if m[by:by+8, bx:bx+8].all():
                blocks.append([bx, by] + r[by:by+8, bx:bx+8].reshape(-1, 3).mean(0).tolist() + nz[by:by+8, bx:bx+8].reshape(-1, 3).mean(0).tolist())
    seeds = json.load(open(f"ref/{case}-seeds.json")) if os.path.exists(f"ref/{case}-seeds.json") else None
    made = (f"{len(seeds['seeds'])} x {seeds['spp_per_seed']} spp (seeds {', '.join(map(str, seeds['seeds']))})"
            if seeds else "2 x 512 spp (seeds 1, 2)")
    out = {"case": case, "material": s["name"], "scene_toml": toml_of(case),
           "reference": f"Mitsuba 3.9.1 scalar_rgb volpathmis, {made}, mirror reflection of the lights removed analytically",
           "pixels": rows, "mean": r[m].mean(0).tolist(),
           "terminator": r[band].mean(0).tolist() if band.any() else None, "blocks": blocks}
    if seeds:
        out["mean_relative_se"] = seeds["mean_relative_se"]
    json.dump(out, open(f"{OUT}/{case}.json", "w"), indent=0)
    print(case, m.sum(), band.sum(), len(blocks))
