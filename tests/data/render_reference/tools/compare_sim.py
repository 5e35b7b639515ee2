"""compare_sim.py QHM.exr SIM.exr -> mean ratio qhm / sim per channel and 8 x 8-block relative RMSE,
over the pixels whose 4-neighbours all see the object in both (qhm render against qhm sim render-object)"""
import sys, numpy as np
sys.argv, args = sys.argv[:1], sys.argv[1:]
import os
exec(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), 'compare.py')).read().split('def main():')[0])
q = load(args[0])[..., :3]; s = load(args[1])[..., :3]
m = (s.sum(-1) > 0) & (q.sum(-1) > 0)
e = m.copy(); e[1:] &= m[:-1]; e[:-1] &= m[1:]; e[:, 1:] &= m[:, :-1]; e[:, :-1] &= m[:, 1:]
qb, sb = [], []
for by in range(0, e.shape[0], 8):
    for bx in range(0, e.shape[1], 8):
        if e[by:by+8, bx:bx+8].all():
            qb.append(q[by:by+8, bx:bx+8].reshape(-1, 3).mean(0)); sb.append(s[by:by+8, bx:bx+8].reshape(-1, 3).mean(0))
qb, sb = np.array(qb), np.array(sb)
print("mean", "/".join("%.3f" % x for x in q[e].mean(0) / s[e].mean(0)),
      "blocks", "/".join("%.3f" % x for x in np.sqrt(((qb - sb) ** 2).mean(0) / (sb ** 2).mean(0))), "pixels", int(e.sum()))
