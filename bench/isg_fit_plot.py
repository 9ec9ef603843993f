"""Error of the seed's ISG sigmoid fit and of the table evaluation (tests/isg64.py)
against the exact normalised ISG, by lam: prints the markdown tables of
docs/isg.md and writes docs/images/isg_fit_error.png.

    python bench/isg_fit_plot.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import isg64 as g  # noqa: E402
from test_isg64 import COSINE_LAMBDAS, cosine_errors, eval_error, seed_fit_error  # noqa: E402

DOC_LAMBDAS = [1e-3, 0.01, 0.1, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0, 3000.0, 1e4]


def main() -> None:
    print("| λ | seed fit | table evaluation |\n|---|---|---|")
    for lam in DOC_LAMBDAS:
        print(f"| {lam:g} | {seed_fit_error(lam):.4f} | {eval_error(lam):.4f} |")
    print("\n| approximation | max | RMS |\n|---|---|---|")
    for name, fn in [("seed single SG", g.sg_cosine_seed), ("closed form (3.3)", g.sg_cosine_closed)]:
        worst, rms = cosine_errors(fn)
        print(f"| {name} | {100 * worst.max():.2f} % | {100 * rms.max():.2f} % |")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lams = 10.0 ** np.linspace(-3, 4, 57)
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    ax[0].loglog(lams, [seed_fit_error(lam) for lam in lams], label="seed sigmoid fit (eq. 14)")
    ax[0].loglog(lams, [eval_error(lam) for lam in lams], label="table evaluation")
    ax[0].axhline(0.01, color="k", lw=0.7, ls="--", label="requirement 0.01")
    ax[0].set_xlabel("λ")
    ax[0].set_ylabel("max |error| of normalised ISG")
    ax[0].legend(fontsize=8)
    for name, fn in [("seed single SG", g.sg_cosine_seed), ("closed form (3.3)", g.sg_cosine_closed)]:
        ax[1].loglog(COSINE_LAMBDAS, np.maximum(cosine_errors(fn)[0], 1e-8), label=name)
    ax[1].set_xlabel("λ")
    ax[1].set_ylabel("max |error| / E(1)")
    ax[1].set_title("SG × clamped cosine")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    out = ROOT / "docs" / "images" / "isg_fit_error.png"
    fig.savefig(out, dpi=90)
    print(f"\nwrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
