"""OpenCV's Debevec pipeline on the same brackets as qhm's bench, for comparison.

Run after `cargo run --release -p qhm-imaging --example bench -- DIR`:
    python3 bench/hdr_opencv.py DIR
Needs opencv-python-headless and numpy (pip). Prints OpenCV's CalibrateDebevec
and MergeDebevec times and the accuracy of its merge and of qhm's (DIR/qhm_hdr.exr
is not read: EXR support in OpenCV builds varies; qhm's accuracy is printed by
the bench itself with the same measure).
"""

import sys
import time

import cv2
import numpy as np


def ramp_irradiance(w, h, c):
    """synth::ramp_irradiance for the whole image, channel c (RGB order)."""
    u, v = np.meshgrid(np.arange(w) / (w - 1), np.arange(h) / (h - 1))
    gain = [1.0, 0.8, 0.55][c]
    e = gain * 10.0 ** (-3.5 + 4.5 * u) * (1.0 + 0.3 * v)
    e[(u > 0.95) & (v < 0.1)] = 1e6  # the specular patch: clipped in every exposure
    return e


def exposure_of(z, gamma=2.2, a=0.08):
    hh = z / 255.0
    y = hh / (1.0 + a - a * hh)
    return y ** gamma


def main():
    d = sys.argv[1] if len(sys.argv) > 1 else "target/bench-hdr"
    times = np.array([float(t) for t in open(f"{d}/exposures.txt").read().split()], dtype=np.float32)
    imgs = [cv2.imread(f"{d}/bracket_{k}.png", cv2.IMREAD_COLOR) for k in range(len(times))]
    h, w = imgs[0].shape[:2]

    t0 = time.perf_counter()
    calib = cv2.createCalibrateDebevec()
    response = calib.process(imgs, times)
    t_cal = time.perf_counter() - t0

    merge = cv2.createMergeDebevec()
    merge.process(imgs, times, response)  # warm up
    reps = 5
    t0 = time.perf_counter()
    for _ in range(reps):
        hdr = merge.process(imgs, times, response)
    t_merge = (time.perf_counter() - t0) / reps
    mp = w * h * len(times) / 1e6
    print(f"OpenCV {cv2.__version__}: CalibrateDebevec {t_cal:.3f} s, MergeDebevec {t_merge * 1e3:.1f} ms "
          f"= {mp / t_merge:.1f} input MP/s (threads: {cv2.getNumThreads()})")

    # Same accuracy measure as the qhm bench: every 4th pixel where the longest
    # exposure reaches Z >= 20 and the shortest is not clipped; one scale per channel.
    errs = []
    for c in range(3):
        e = ramp_irradiance(w, h, c) * 8.0
        v = hdr[:, :, 2 - c].astype(np.float64)  # OpenCV is BGR
        sel = np.zeros_like(e, dtype=bool)
        sel[::4, ::4] = True
        sel &= (e * times.max() > exposure_of(20.0)) & (e * times.min() < 1.0) & np.isfinite(v)
        r = v[sel] / e[sel]
        med = np.median(r)
        errs.append(np.abs(r / med - 1.0))
    errs = np.concatenate(errs)
    print(f"OpenCV merge vs truth: median |rel err| {np.median(errs):.4f}, 95th percentile "
          f"{np.percentile(errs, 95):.4f} ({errs.size} samples)")
    sat = np.all(np.stack(imgs) >= 250, axis=0).any(axis=2)
    print(f"pixels clipped in every exposure: {int(sat.sum())}; OpenCV gives them "
          f"{'NaN' if np.isnan(hdr[sat]).all() else 'finite values (averaged clipped data)'}")


if __name__ == "__main__":
    main()
