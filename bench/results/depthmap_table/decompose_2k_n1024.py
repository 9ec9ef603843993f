"""2k (the 1k map repeated 2 x 2) at N = 1024 alone, as env_domains_experiments.py `time` does it (run from the repo root)."""
import os
import sys

sys.path.insert(0, "bench")
import env_domains_experiments as e  # noqa: E402
import numpy as np  # noqa: E402

import penumbra  # noqa: E402

ctx = penumbra.Context()
base = e.load(e.TIME_MAP, False)
big = np.repeat(np.repeat(base, 2, axis=0), 2, axis=1)
e.timed_decompose(ctx, base, 4, 1)
print("load", os.getloadavg(), flush=True)
one = e.timed_decompose(ctx, big, 1024, 1)
print(f"2k N=1024 one iteration {one:.2f} s load {os.getloadavg()}", flush=True)
full = e.timed_decompose(ctx, big, 1024)
print(f"2k N=1024 full {full:.2f} s load {os.getloadavg()}", flush=True)
