"""teapot_parts.py QHM.exr SIM1.exr[,SIM2.exr]: qhm render against `qhm sim render-object` (the mean of the
seeds given) over the pixels whose 4-neighbours all see the object in both: mean ratio per channel, 8 x 8-block
relative RMSE (as compare_sim.py), and the mean ratio over the handle (the object's left fifth of columns)
and the spout (its right 28 %) of the built-in teapot seen from the default camera."""
import sys, numpy as np, mitsuba as mi
mi.set_variant('scalar_rgb')
ld=lambda p: np.array(mi.Bitmap(p))[..., :3]
q=ld(sys.argv[1]); sims=[ld(p) for p in sys.argv[2].split(',')]; s=sum(sims)/len(sims)
m=(s.sum(-1)>0)&(q.sum(-1)>0)
e=m.copy(); e[1:]&=m[:-1]; e[:-1]&=m[1:]; e[:,1:]&=m[:,:-1]; e[:,:-1]&=m[:,1:]
qb,sb,nb=[],[],[]
for by in range(0,e.shape[0],8):
    for bx in range(0,e.shape[1],8):
        if e[by:by+8,bx:bx+8].all():
            qb.append(q[by:by+8,bx:bx+8].reshape(-1,3).mean(0)); sb.append(s[by:by+8,bx:bx+8].reshape(-1,3).mean(0))
            if len(sims)==2: nb.append(np.abs(sims[0][by:by+8,bx:bx+8].reshape(-1,3).mean(0)-sims[1][by:by+8,bx:bx+8].reshape(-1,3).mean(0))/2)
qb,sb=np.array(qb),np.array(sb)
rel=(qb/sb-1)
rm=np.sqrt((rel**2).mean(0))
if nb: rm=np.sqrt(np.maximum((rel**2).mean(0)-((np.array(nb)/sb)**2).mean(0),0))
cols=np.where(e.any(0))[0]; x0,x1=cols[0],cols[-1]; w=x1-x0+1
hm=e.copy(); hm[:, x0+int(0.2*w):]=False
sp=e.copy(); sp[:, :x1+1-int(0.28*w)]=False
f=lambda mask: "/".join("%.3f"%v for v in q[mask].mean(0)/s[mask].mean(0))
cs=np.sqrt(((qb-sb)**2).mean(0)/(sb**2).mean(0))
print("mean",f(e),"blocks","/".join("%.1f%%"%(100*v) for v in cs),"handle",f(hm),"spout",f(sp))
