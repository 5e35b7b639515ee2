"""runqhm.py SCENE.json OUT.exr [--mode M] [--samples N] [--spp N] [--seed S] [--extra k=v ...] : qhm render of the same scene"""
import json, math, subprocess, sys, os, numpy as np
QHM = os.environ.get("QHM", "target/release/qhm")
def disk_dirs(l, alpha, n=32):
    l = np.array(l, float); l /= np.linalg.norm(l)
    a = np.cross(l, [0, 0, 1.0]) if abs(l[2]) < 0.9 else np.cross(l, [1.0, 0, 0]); a /= np.linalg.norm(a)
    b = np.cross(l, a); out = []
    for k in range(n):
        r = math.tan(alpha) * math.sqrt((k + 0.5) / n); p = k * 2.399963
        d = l + r * (math.cos(p) * a + math.sin(p) * b); out.append(d / np.linalg.norm(d))
    return out
def main():
    a = sys.argv[1:]; scene, out = a[0], a[1]
    opt = {"--mode": "full", "--samples": "30000", "--spp": "4", "--seed": "1"}
    extra = []
    i = 2
    while i < len(a):
        if a[i] == "--extra": extra.append(a[i + 1])
        else: opt[a[i]] = a[i + 1]
        i += 2
    s = json.load(open(scene))
    t = ["[camera]", f"eye = {s['eye']}", f"target = {s['target']}", "up = [0, 0, 1]", f"fov_deg = {s['fov_deg']}"]
    if "sun" in s:
        su = s["sun"]; dirs = disk_dirs(su["to_light"], math.radians(su["half_angle_deg"]))
        for d in dirs:
            e = su["irradiance"] / len(dirs)
            t += ["[[lights]]", 'kind = "directional"', f"direction = {list(map(float, d))}", f"irradiance = [{e}, {e}, {e}]"]
    else:
        t += ["[[lights]]", 'kind = "directional"', "direction = [0, 0, 1]", "irradiance = [0, 0, 0]"]
    if "env" not in s:
        t += ["[env]", 'builtin = "none"']
    if "env" in s:
        t += ["[env]", f'file = "{os.path.abspath(s["env"]["file"])}"', f"scale = {s['env'].get('scale', 1.0)}", "visible = false"]
    t += ["[render]", f'mode = "{opt["--mode"]}"', f"width = {s['width']}", f"height = {s['height']}",
          f"spp = {opt['--spp']}", f"surface_samples = {opt['--samples']}", f"seed = {opt['--seed']}"] + extra
    toml = out + ".toml"; open(toml, "w").write("\n".join(t) + "\n")
    # no lights of the default scene: an explicit empty list keeps none when env only
    if os.environ.get("VARIANT") is not None:
        cmd = [os.environ.get("VARIANTS", "target/release/examples/variants"), toml, s["name"], out] + os.environ["VARIANT"].split()
    else:
        cmd = [QHM, "render", "--model", f"builtin:{s['name']}", "--builtin", "sphere", "--scene", toml, "-o", out, "--force", "--quiet"]
    subprocess.run(cmd, check=True)
main()
