"""Spherical-Gaussian lighting (docs/isg.md): the SG lobe record shared with
the C API (pn_sg_lobe) and the ISG table built by the library."""

from __future__ import annotations

import numpy as np

from ._native import call

# pn_sg_lobe: axis[3], sharpness, amplitude[3], pad (32 bytes, the device layout).
SG_LOBE = np.dtype([("axis", np.float32, 3), ("sharpness", np.float32), ("amplitude", np.float32, 3),
                    ("pad", np.float32)])
assert SG_LOBE.itemsize == 32

ISG_TABLE_SHAPE = (4, 57, 33)  # front theta, front phi, back theta, back phi; lambda rows; rho columns
ISG_TABLE_FLOATS = 4 * 57 * 33


def isg_table() -> np.ndarray:
    """The (4, 57, 33) float32 ISG table that kernels/common/sg.cl's pn_isg reads,
    built by the library in float64 (pn_isg_table)."""
    out = np.empty(ISG_TABLE_FLOATS, np.float32)
    call("pn_isg_table", None, out.ctypes.data, out.size)
    return out.reshape(ISG_TABLE_SHAPE)
