"""compare.py QHM.exr REF_A.exr REF_B.exr SCENE.json [QHM_SS.exr] -> metrics json line"""
import json, math, sys, numpy as np, mitsuba as mi
mi.set_variant('scalar_rgb')
def load(p):
    a = np.array(mi.Bitmap(p), dtype=np.float64)
    return a
def normals(s):
    W, H = s["width"], s["height"]
    eye, tgt = np.array(s["eye"], float), np.array(s["target"], float)
    fwd = (tgt - eye) / np.linalg.norm(tgt - eye)
    right = np.cross(fwd, [0, 0, 1.0]); right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tan = math.tan(math.radians(s["fov_deg"]) / 2)
    c = np.array(s["sphere"]["center"], float); R = s["sphere"]["radius"]
    n = np.zeros((H, W, 3)); hit = np.zeros((H, W), bool)
    for y in range(H):
        for x in range(W):
            sx = (2 * (x + .5) / W - 1) * tan; sy = (1 - 2 * (y + .5) / H) * tan
            d = fwd + right * sx + up * sy; d /= np.linalg.norm(d)
            oc = eye - c; b = oc @ d; cc = oc @ oc - R * R; disc = b * b - cc
            if disc > 0:
                t = -b - math.sqrt(disc); p = eye + t * d
                n[y, x] = (p - c) / R; hit[y, x] = True
    return n, hit
ETA = {"skin1": 1.3, "apple": 1.3, "ketchup": 1.3, "marble": 1.5}
def fresnel(ci, eta):
    st2 = (1 - ci * ci) / (eta * eta)
    if st2 >= 1: return 1.0
    ct = math.sqrt(1 - st2)
    rs = (ci - eta * ct) / (ci + eta * ct); rp = (eta * ci - ct) / (eta * ci + ct)
    return 0.5 * (rs * rs + rp * rp)
def env_bilinear(env, d):
    H, W = env.shape[:2]
    t = math.acos(max(-1, min(1, d[2]))); p = math.atan2(d[1], d[0]) % (2 * math.pi)
    x = p / (2 * math.pi) * W - 0.5; y = t / math.pi * H - 0.5
    x0 = math.floor(x); y0 = math.floor(y); fx = x - x0; fy = y - y0
    def px(i, j): return env[min(max(j, 0), H - 1), i % W, :3]
    return ((1 - fx) * (1 - fy) * px(x0, y0) + fx * (1 - fy) * px(x0 + 1, y0)
            + (1 - fx) * fy * px(x0, y0 + 1) + fx * fy * px(x0 + 1, y0 + 1))
def specular(s, k=4):
    """The smooth boundary's mirror reflection of the lights, per pixel (box filter, k x k rays)."""
    W, H = s["width"], s["height"]
    eye, tgt = np.array(s["eye"], float), np.array(s["target"], float)
    fwd = (tgt - eye) / np.linalg.norm(tgt - eye)
    right = np.cross(fwd, [0, 0, 1.0]); right /= np.linalg.norm(right)
    up = np.cross(right, fwd); tan = math.tan(math.radians(s["fov_deg"]) / 2)
    c = np.array(s["sphere"]["center"], float); R = s["sphere"]["radius"]; eta = ETA[s["name"]]
    env = load(s["env"]["file"]) * s["env"].get("scale", 1.0) if "env" in s else None
    if "sun" in s:
        l = np.array(s["sun"]["to_light"], float); l /= np.linalg.norm(l)
        a = math.radians(s["sun"]["half_angle_deg"]); Ls = s["sun"]["irradiance"] / (math.pi * math.sin(a) ** 2)
    out = np.zeros((H, W, 3))
    for y in range(H):
        for x in range(W):
            acc = np.zeros(3)
            for i in range(k):
                for j in range(k):
                    sx = (2 * (x + (i + .5) / k) / W - 1) * tan; sy = (1 - 2 * (y + (j + .5) / k) / H) * tan
                    d = fwd + right * sx + up * sy; d /= np.linalg.norm(d)
                    oc = eye - c; b = oc @ d; disc = b * b - (oc @ oc - R * R)
                    if disc <= 0: continue
                    p = eye + (-b - math.sqrt(disc)) * d; n = (p - c) / R
                    ci = -d @ n; F = fresnel(ci, eta); r = d + 2 * ci * n
                    if env is not None: acc += F * env_bilinear(env, r)
                    if "sun" in s and r @ l > math.cos(a): acc += F * Ls
            out[y, x] = acc / (k * k)
    return out
def eroded(m):
    """m less its edge pixels (which mix the background)."""
    e = m.copy(); e[1:] &= m[:-1]; e[:-1] &= m[1:]; e[:, 1:] &= m[:, :-1]; e[:, :-1] &= m[:, 1:]
    return e
def compared(s, alpha):
    """The sphere's normals and the pixels compared: fully covered (alpha), edge pixels left out."""
    n, hit = normals(s)
    return n, eroded(hit & (alpha > 0.999))
def blocks(img, m, k=8):
    H, W = m.shape; out = []; idx = []
    for by in range(0, H, k):
        for bx in range(0, W, k):
            if m[by:by+k, bx:bx+k].all():
                out.append(img[by:by+k, bx:bx+k].reshape(-1, 3).mean(0))
    return np.array(out)
def main():
    q = load(sys.argv[1])[..., :3]; A = load(sys.argv[2]); B = load(sys.argv[3])
    s = json.load(open(sys.argv[4]))
    alpha = np.minimum(A[..., 3], B[..., 3]); A = A[..., :3]; B = B[..., :3]
    n, m = compared(s, alpha)
    spec = specular(s)
    A = A - spec; B = B - spec
    r = 0.5 * (A + B); noise = 0.5 * (A - B)
    res = {"scene": sys.argv[4].split('/')[-1]}
    res["mean_ratio"] = [float(q[m][:, c].mean() / r[m][:, c].mean()) for c in range(3)]
    lum = lambda x: x @ np.array([0.2126, 0.7152, 0.0722])
    res["lum_ratio"] = float(lum(q[m]).mean() / lum(r[m]).mean())
    qb, rb, nb = blocks(q, m), blocks(r, m), blocks(noise, m)
    if len(rb):
        err2 = ((qb - rb) ** 2).mean(0) - (nb ** 2).mean(0)
        res["block_rmse"] = [float(math.sqrt(max(e, 0)) / math.sqrt((rb[:, c] ** 2).mean())) for c, e in enumerate(err2)]
        res["ref_block_noise"] = [float(math.sqrt((nb[:, c] ** 2).mean() / (rb[:, c] ** 2).mean())) for c in range(3)]
    if "sun" in s:
        l = np.array(s["sun"]["to_light"], float); l /= np.linalg.norm(l)
        nl = n @ l
        band = m & (np.abs(nl) < 0.25)
        if band.sum() > 4:
            res["terminator_ratio"] = [float(q[band][:, c].mean() / r[band][:, c].mean()) for c in range(3)]
            res["terminator_px"] = int(band.sum())
        rim = m & (n @ (np.array(s["eye"]) - np.array(s["target"])) / np.linalg.norm(np.array(s["eye"]) - np.array(s["target"])) < 0.3)
        lit_rim = rim & (nl > 0.25)
        if lit_rim.sum() > 4:
            res["rim_ratio"] = [float(q[lit_rim][:, c].mean() / r[lit_rim][:, c].mean()) for c in range(3)]
    if len(sys.argv) > 5:
        ss = load(sys.argv[5])[..., :3]
        sb = blocks(ss, m)
        res["mottling"] = [float(math.sqrt(((qb[:, c] - sb[:, c]) ** 2).mean() / (sb[:, c] ** 2).mean())) for c in range(3)]
    print(json.dumps({k: (np.round(v, 4).tolist() if isinstance(v, list) else v) for k, v in res.items()}))
main()
