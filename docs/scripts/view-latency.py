#!/usr/bin/env python3
"""view-latency.py QHM MODEL MESH SIZE light|camera

Starts `QHM view MODEL --port 0`, renders every level once at a first view,
then moves the light (or the camera) three times by 20 degrees, requesting
the levels in turn over POST /api/render, and prints the renderer's time of
each level (the x-qhm-ms header) and their sum: the time from a change to
its first image and to the final level (`qhm render`'s default quality)."""
import json
import re
import subprocess
import sys
import urllib.request


def main():
    if len(sys.argv) != 6 or sys.argv[5] not in ("light", "camera"):
        sys.exit(__doc__.splitlines()[0])
    qhm, model, mesh, size, what = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5]
    view = subprocess.Popen([qhm, "view", model, "--port", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    try:
        url = None
        while url is None:
            line = view.stdout.readline()
            if not line:
                sys.exit("qhm view ended before printing its address")
            m = re.search(r"(http://127\.0\.0\.1:\d+)", line)
            url = m.group(1) if m else None

        def render(level, camera_az, light_az):
            body = {"mesh": mesh, "mode": "full", "env": "studio", "width": size, "height": size,
                    "camera": {"azimuth_deg": camera_az, "elevation_deg": 20, "distance": 3},
                    "light": {"azimuth_deg": light_az, "elevation_deg": 40, "irradiance": 2},
                    "exposure": 1, "level": level}
            req = urllib.request.Request(url + "/api/render", data=json.dumps(body).encode(),
                                         headers={"content-type": "application/json"})
            with urllib.request.urlopen(req) as r:
                r.read()
                return float(r.headers["x-qhm-ms"]) / 1000

        levels = int(urllib.request.urlopen(url + "/api/render", data=json.dumps({
            "mesh": mesh, "width": size, "height": size, "level": 0}).encode()).headers["x-qhm-levels"])
        for level in range(levels):
            render(level, 30, 60)
        for k in range(1, 4):
            camera, light = (30, 60 + 20 * k) if what == "light" else (30 + 20 * k, 60)
            t = [render(level, camera, light) for level in range(levels)]
            print(f"{what} move on the {mesh}, {size} x {size}: first image {t[0] * 1000:.0f} ms, "
                  f"final level {sum(t):.2f} s ({' + '.join(f'{x:.2f}' for x in t)})")
    finally:
        view.terminate()


main()
