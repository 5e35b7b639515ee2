"""merge_seeds.py CASE SPP SEED...: the reference's two halves from renders of independent seeds.

Reads ref/CASE-seedK.exr for each SEED (SPP samples per pixel each) and writes
ref/CASE-s1.exr (the mean of the odd-placed seeds) and ref/CASE-s2.exr (the
even-placed ones), which compare.py and cache.py take as the reference's two
halves: their mean is the reference, half their difference its noise. Writes
ref/CASE-seeds.json with what was merged and the relative standard error of
the mean over the compared pixels from the seeds' scatter, which on the
back-lit spheres is far above what two halves can show."""
import json, os, sys
import numpy as np
args = sys.argv[1:]; sys.argv = sys.argv[:1]
exec(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), 'compare.py')).read().split('def main():')[0])
if len(args) < 4 or len(args) % 2:
    sys.exit("usage: merge_seeds.py CASE SPP SEED SEED [SEED SEED ...] (an even count of seeds)")
case, spp, seeds = args[0], int(args[1]), args[2:]
imgs = [load(f"ref/{case}-seed{k}.exr") for k in seeds]
for name, half in (("s1", imgs[0::2]), ("s2", imgs[1::2])):
    # Alpha is the pixel's coverage, seen by every seed alike: a pixel
    # counts as inside only if every seed saw it so (as two seeds did).
    merged = np.mean(half, 0)
    merged[..., 3] = np.min([im[..., 3] for im in half], 0)
    mi.Bitmap(merged.astype(np.float32)).write(f"ref/{case}-{name}.exr")
s = json.load(open(f"ref/{case}.json"))
_, e = compared(s, np.min([im[..., 3] for im in imgs], 0))
spec = specular(s)
means = np.array([(im[..., :3] - spec)[e].mean(0) for im in imgs])
se = means.std(0, ddof=1) / np.sqrt(len(imgs)) / means.mean(0)
out = {"case": case, "seeds": [int(k) for k in seeds], "spp_per_seed": spp,
       "mean_relative_se": np.round(se, 4).tolist()}
json.dump(out, open(f"ref/{case}-seeds.json", "w"))
print(json.dumps(out))
