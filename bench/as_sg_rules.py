"""The row-of-SGs rules of the anisotropic lobe (docs/isg.md 6, pn_as_sgs):
L1 error of 7 isotropic Gaussians of width s_c, spaced by d along the long
axis with Gaussian weights of variance r^2 - s_c^2, against the anisotropic
Gaussian of widths r (long) and 1 (short) in the plane, normalised to the
same integral. Prints the best (s_c, d) found by a grid search and the error
of the rules s_c = max(1, sqrt(r / 4.3)), d = min(0.8 s_w, 2.4 s_c).

    .venv/bin/python bench/as_sg_rules.py
"""

from __future__ import annotations

import numpy as np

COUNT = 7


def row_error(r: float, s_c: float, d: float) -> float:
    x = np.linspace(-4 * r - 4, 4 * r + 4, 601)
    y = np.linspace(-6, 6, 161)
    xx, yy = np.meshgrid(x, y)
    target = np.exp(-xx ** 2 / (2 * r * r) - yy ** 2 / 2)
    var_w = max(r * r - s_c * s_c, 1e-12)
    centres = d * (np.arange(COUNT) - (COUNT - 1) / 2)
    row = sum(np.exp(-c * c / (2 * var_w)) * np.exp(-((xx - c) ** 2 + yy ** 2) / (2 * s_c * s_c)) for c in centres)
    row *= target.sum() / row.sum()
    return float(np.abs(row - target).sum() / target.sum())


def rules(r: float) -> tuple[float, float]:
    s_c = max(1.0, np.sqrt(r / 4.3))
    s_w = np.sqrt(max(r * r - s_c * s_c, 0.0))
    return s_c, max(min(0.8 * s_w, 2.4 * s_c), 1e-9)


def main() -> None:
    print("| r = s_t / s_s | best L1 (s_c, d / s_c) | rules L1 |")
    print("|---|---|---|")
    for r in (1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.0, 10.0, 20.0):
        best = (np.inf, 0.0, 0.0)
        for s_c in np.linspace(1.0, max(1.0, 0.9 * r), 20):
            s_w = np.sqrt(max(r * r - s_c * s_c, 1e-12))
            for k in np.linspace(0.3, 1.3, 21):
                e = row_error(r, s_c, k * s_w)
                if e < best[0]:
                    best = (e, s_c, k * s_w / s_c)
        print(f"| {r:g} | {best[0]:.3f} ({best[1]:.2f}, {best[2]:.2f}) | {row_error(r, *rules(r)):.3f} |")


if __name__ == "__main__":
    main()
