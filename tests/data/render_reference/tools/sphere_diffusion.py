"""sphere_diffusion.py PRESET [RADIUS_MM [LIGHT_DEG]] : diffusion theory's exitance at a sphere's point against a plane's.

Exact diffusion in a sphere (the screened Poisson equation with the Robin
boundary phi + 2AD dphi/dn = 0, solved as a Legendre series in modified
spherical Bessel functions), lit by one directional light LIGHT_DEG
(default 36.87) off the point's normal (the set-up of docs/render.md, "What the curvature adds"):
each surface point takes in E = cos T(cos) and holds a point source of
strength a' one reduced mean free path under it, along its normal. Prints
the exitance at the point over the plane's under the same light. Needs scipy.
"""
import math
import sys
import numpy as np
from scipy.special import ive

PRESETS = {  # sigma_s', sigma_a (mm^-1), eta, as host/render/src/materials.rs
    "apple": ([2.29, 2.39, 1.97], [0.0030, 0.0034, 0.046], 1.3),
    "skin1": ([0.74, 0.88, 1.01], [0.032, 0.17, 0.48], 1.3),
    "marble": ([2.19, 2.62, 3.00], [0.0021, 0.0041, 0.0071], 1.5),
    "skin2": ([1.09, 1.59, 1.79], [0.013, 0.070, 0.145], 1.3),
}


def fresnel_t(c, eta):
    c = np.clip(c, 1e-9, 1.0)
    ct = np.sqrt(np.maximum(1 - (1 - c * c) / eta**2, 0))
    rs = ((c - eta * ct) / (c + eta * ct)) ** 2
    rp = ((eta * c - ct) / (eta * c + ct)) ** 2
    return 1 - (rs + rp) / 2


def log_i(nmax, y):
    """log i_n(y), n = 0..nmax (i_n = sqrt(pi / 2y) I_{n+1/2}, scaled to avoid overflow)."""
    v = np.arange(nmax + 1) + 0.5
    return 0.5 * np.log(np.pi / (2 * y)) + np.log(np.maximum(ive(v, y), 1e-300)) + y


def exitance_coefficients(a, s_s, s_a, eta, nmax):
    """G_n with M(gamma) = sum_n G_n P_n(cos gamma): exitance at angle gamma from a unit source."""
    s_t = s_s + s_a
    d = 1 / (3 * s_t)
    k = np.sqrt(s_a / d)
    f_dr = -1.44 / eta**2 + 0.71 / eta + 0.668 + 0.0636 * eta
    big_a = (1 + f_dr) / (1 - f_dr)
    h = 2 * big_a * d * k
    x = k * a
    li = log_i(nmax + 1, x)
    li0 = log_i(nmax, k * (a - 1 / s_t))
    n = np.arange(nmax + 1)
    di_over_i = np.exp(li[1:] - li[:-1]) + n / x  # i_n' = i_{n+1} + n i_n / x
    # the Robin condition's coefficient with the Wronskian k_n i_n' - i_n k_n' = pi / 2x^2
    fluence = (k / (2 * np.pi**2 * d)) * (2 * n + 1) * np.exp(li0 - li[:-1]) / (1 + h * di_over_i) * h * np.pi / (2 * x * x)
    return (s_s / s_t) / (2 * big_a) * fluence  # exitance = phi / 2A, source strength a'


def main():
    name = sys.argv[1]
    a = float(sys.argv[2]) if len(sys.argv) > 2 else 20.0
    s_s, s_a, eta = PRESETS[name]
    deg = float(sys.argv[3]) if len(sys.argv) > 3 else math.degrees(math.atan2(0.6, 0.8))
    light = np.array([math.sin(math.radians(deg)), -math.cos(math.radians(deg)), 0.0])
    no = np.array([0.0, -1.0, 0.0])
    g = np.linspace(0, np.pi, 20001)
    gm, dg = 0.5 * (g[1:] + g[:-1]), np.diff(g)
    t1 = np.array([1.0, 0, 0])
    t2 = np.cross(no, t1)
    e_ring = np.zeros_like(gm)  # irradiance, averaged over each ring around the point
    for p in (np.arange(256) + 0.5) * 2 * np.pi / 256:
        nn = np.cos(gm)[:, None] * no + np.sin(gm)[:, None] * (np.cos(p) * t1 + np.sin(p) * t2)
        c = nn @ light
        e_ring += np.where(c > 0, c * fresnel_t(c, eta), 0) / 256
    e0 = -light[1] * fresnel_t(-light[1], eta)
    out = []
    for ch in range(3):
        nmax = int(12 * a * (s_s[ch] + s_a[ch])) + 50
        gn = exitance_coefficients(a, s_s[ch], s_a[ch], eta, nmax)
        cg, w = np.cos(gm), e_ring * np.sin(gm) * dg * 2 * np.pi * a * a
        p0, p1 = np.ones_like(cg), cg.copy()
        m = gn[0] * w.sum() + gn[1] * (w * p1).sum()
        for n in range(1, nmax):
            p0, p1 = p1, ((2 * n + 1) * cg * p1 - n * p0) / (n + 1)
            m += gn[n + 1] * (w * p1).sum()
        # the plane: a sphere so large that only uniform light matters
        big = 2e4
        plane = exitance_coefficients(big, s_s[ch], s_a[ch], eta, 0)[0] * 4 * np.pi * big * big
        out.append(m / (e0 * plane))
    print(f"{name}, radius {a:g} mm, light {deg:.1f} deg: exitance at the point over the plane's  " + " / ".join(f"{v:.3f}" for v in out))


if __name__ == "__main__":
    main()
