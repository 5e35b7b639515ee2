"""teapot_parts.py QHM.exr SIM1.exr[,SIM2.exr]: qhm render against `qhm sim render-object` (the mean of the
seeds given) over the pixels whose 4-neighbours all see the object in both: mean ratio per channel, 8 x 8-block
relative RMSE (as compare_sim.py), and the mean ratio over the handle (the object's left fifth of columns)
and the spout (its right 28 %) of the built-in teapot seen from the default camera."""
import sys, numpy as np, mitsuba as mi
mi.set_variant('scalar_rgb')
ld = lambda p: np.array(mi.Bitmap(p))[..., :3]
q = ld(sys.argv[1]); sims = [ld(p) for p in sys.argv[2].split(',')]; s = sum(sims) / len(sims)
m = (s.sum(-1) > 0) & (q.sum(-1) > 0)
e = m.copy(); e[1:] &= m[:-1]; e[:-1] &= m[1:]; e[:, 1:] &= m[:, :-1]; e[:, :-1] &= m[:, 1:]
blocks = [(y, x) for y in range(0, e.shape[0], 8) for x in range(0, e.shape[1], 8) if e[y:y+8, x:x+8].all()]
qb = np.array([q[y:y+8, x:x+8].reshape(-1, 3).mean(0) for y, x in blocks])
sb = np.array([s[y:y+8, x:x+8].reshape(-1, 3).mean(0) for y, x in blocks])
rmse = np.sqrt(((qb - sb) ** 2).mean(0) / (sb ** 2).mean(0))
cols = np.where(e.any(0))[0]; x0, x1 = cols[0], cols[-1]; w = x1 - x0 + 1
handle = e.copy(); handle[:, x0 + int(0.2 * w):] = False
spout = e.copy(); spout[:, :x1 + 1 - int(0.28 * w)] = False
ratio = lambda mask: "/".join("%.3f" % v for v in q[mask].mean(0) / s[mask].mean(0))
print("mean", ratio(e), "blocks", "/".join("%.1f%%" % (100 * v) for v in rmse), "handle", ratio(handle), "spout", ratio(spout))
