"""SPH kernels in 2D, with support radius h, each integrating to 1 over the disc r < h.

The thesis printed the 3D normalisations (315/(64 pi h^9), 15/(pi h^6)); in 2D they are:
  poly6     4 / (pi h^8) (h^2 - r^2)^3
  spiky     10 / (pi h^5) (h - r)^3
  cubic     Monaghan's cubic spline with smoothing length h/2 (support h), sigma = 40 / (7 pi h^2)
  gaussian  exp(-(r/s)^2) with s = h/2, truncated at h and renormalised over the disc
The native splatter (deepcontact/native/splat.cpp) uses the same formulas.
"""
import numpy as np

KERNELS = {"poly6": 0, "spiky": 1, "cubic": 2, "gaussian": 3}


def weight(kernel, r, h):
    r = np.asarray(r, dtype=np.float64)
    inside = r < h
    if kernel == "poly6":
        w = 4.0 / (np.pi * h ** 8) * (h * h - r * r) ** 3
    elif kernel == "spiky":
        w = 10.0 / (np.pi * h ** 5) * (h - r) ** 3
    elif kernel == "cubic":
        q = 2.0 * r / h
        sigma = 40.0 / (7.0 * np.pi * h * h)
        w = np.where(q < 1.0, sigma * (1 - 1.5 * q * q + 0.75 * q ** 3), sigma * 0.25 * np.clip(2.0 - q, 0, None) ** 3)
    elif kernel == "gaussian":
        s = 0.5 * h
        w = np.exp(-(r * r) / (s * s)) / (np.pi * s * s * (1.0 - np.exp(-4.0)))
    else:
        raise ValueError(f"unknown kernel {kernel!r}; choose from {', '.join(KERNELS)}")
    return np.where(inside, w, 0.0)
