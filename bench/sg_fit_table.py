"""Error of the library's env map -> SG lobe fit (pn_envmap_fit_sgs, docs/isg.md 5) by the
number of lobes K, on the maps of ../shared/data/envmaps: prints the markdown tables of
docs/isg.md. Deterministic (the fit is; timings vary with the machine).

  map error:        relative RMS over the committed cube's texels (face 64, solid-angle
                    weighted) of the lobes' radiance against the map's;
  irradiance error: relative RMS over the irradiance map's directions (face 32) of the
                    lobes' closed-form irradiance (tests/isg64.py) against the map's exact
                    irradiance (the sum over its cube texels).

    python bench/sg_fit_table.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import isg64 as g  # noqa: E402
from test_sg_fit import irradiance_directions  # noqa: E402

import penumbra  # noqa: E402
from penumbra.imageio import read_envmap  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "envmaps"
MAPS = [("sunny", "rooitou_park_1k_polyhaven.hdr"), ("sunny", "immenstadter_horn_1k_polyhaven.hdr"),
        ("overcast", "potsdamer_platz_1k_polyhaven.hdr"), ("indoor", "st_fagans_interior_1k_polyhaven.hdr"),
        ("indoor", "studio_small_03_1k_polyhaven.hdr"), ("probe", "grace_probulator_256x128.hdr"),
        ("probe", "uffizi_probulator_256x128.hdr")]
KS = [1, 4, 8, 16, 32, 64, 128]


def main() -> None:
    ctx = penumbra.Context()
    rows_map, rows_irr, seconds = [], [], {k: 0.0 for k in KS}
    for kind, name in MAPS:
        env = penumbra.EnvMap(ctx, read_envmap(DATA / name))
        rad = env.cube_radiance().reshape(-1, 3)
        d, w = env.cube_directions()
        d, w = d.reshape(-1, 3), w.ravel()
        e = env.irradiance().reshape(-1, 3)
        n = irradiance_directions(env.get("irradiance_face_size"))
        env.fit_sgs(1)  # the first read waits for the commit
        m_row, i_row = [], []
        for k in KS:
            t = time.perf_counter()
            lobes = env.fit_sgs(k)
            seconds[k] += time.perf_counter() - t
            ax, lam, amp = lobes["axis"], lobes["sharpness"], lobes["amplitude"]
            m_row.append(g.relative_rms(g.sg_lobes_radiance(ax, lam, amp, d), rad, w))
            i_row.append(g.relative_rms(g.sg_lobes_irradiance(ax, lam, amp, n), e))
        label = f"{name.split('_1k')[0].split('_probulator')[0]} ({kind})"
        rows_map.append((label, m_row))
        rows_irr.append((label, i_row))
    head = "| map | " + " | ".join(f"K={k}" for k in KS) + " |\n|---|" + "---|" * len(KS)
    for title, rows in (("irradiance error", rows_irr), ("map error", rows_map)):
        print(f"\n{title}\n{head}")
        for label, row in rows:
            print(f"| {label} | " + " | ".join(f"{100 * v:.2f} %" for v in row) + " |")
    print("\nfit time per map (mean over the maps, s): " + ", ".join(
        f"K={k}: {seconds[k] / len(MAPS):.2f}" for k in KS))


if __name__ == "__main__":
    main()
