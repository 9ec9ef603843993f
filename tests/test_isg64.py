"""Self-consistency of the float64 ISG reference (tests/isg64.py, docs/isg.md):
SG closed forms against brute-force quadrature on the sphere, the hard cases
(lam = 1e-3 and 1e4, nearly opposite and nearly aligned lobes, a lobe axis
below the horizon), the SG x cosine approximations with their measured error
bounded, the exact ISG against its identities, the seed's fit and the table
evaluation against the exact ISG. The error table in docs/isg.md is read and
checked against fresh measurements, so the page cannot drift.

No kernel yet: this is the twin the ISG kernels will be tested against.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import isg64 as g

DOC = Path(__file__).resolve().parents[1] / "docs" / "isg.md"
RNG_SEED = 20240613
LAMBDAS = [1e-3, 0.1, 1.0, 10.0, 300.0, 1e4]


# --------------------------------------------------------------------------- helpers


def frame(axis):
    """Two unit vectors completing axis to an orthonormal frame."""
    a = np.asarray(axis, float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


def lobe_rule(axis, lam, nodes=16, n_beta=64):
    """Sphere quadrature around `axis`: u = cos(angle) by Gauss-Legendre panels graded on
    the width 1/lam near u = 1 (where a lobe of sharpness lam lives), azimuth by the
    periodic trapezoid rule (spectral for smooth integrands). Directions (n, 3), weights (n,)."""
    u, wu = g.panel_rule(g.graded_breaks(-1.0, 1.0, 1.0, 1.0 / max(lam, 1e-3)), nodes)
    beta = 2 * np.pi * np.arange(n_beta) / n_beta
    e1, e2 = frame(axis)
    s = np.sqrt(np.maximum(0.0, 1 - u * u))
    d = (
        u[:, None, None] * np.asarray(axis, float)
        + (s[:, None] * np.cos(beta))[..., None] * e1
        + (s[:, None] * np.sin(beta))[..., None] * e2
    )
    return d.reshape(-1, 3), (wu[:, None] * np.full(n_beta, 2 * np.pi / n_beta)).ravel()


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def rotated_pair(angle):
    """Two unit vectors at `angle` from each other (angle near pi: nearly opposite)."""
    a1 = unit([0.3, -0.5, 0.8])
    e1, _ = frame(a1)
    return a1, math.cos(angle) * a1 + math.sin(angle) * e1


def doc_table(heading):
    """Rows (lists of cells) of the first table under the markdown `heading` in docs/isg.md."""
    text = DOC.read_text()
    start = text.index(heading)
    rows = []
    for line in text[start:].splitlines()[1:]:
        if line.startswith("#"):
            break
        if line.startswith("|") and not set(line) <= set("|-: "):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
        elif rows and not line.startswith("|"):
            break
    return rows[1:]  # without the header


# --------------------------------------------------------------------------- SG integrals and products


@pytest.mark.parametrize("lam", LAMBDAS)
def test_sg_integral_against_quadrature(lam):
    axis = unit([1.0, 2.0, -0.5])
    d, w = lobe_rule(axis, lam)
    brute = np.dot(w, g.sg(d, axis, lam, 1.7))
    closed = g.sg_integral(lam, 1.7)
    assert np.isfinite(closed)
    assert closed == pytest.approx(brute, rel=1e-11)
    assert g.sg_hemisphere_integral(lam) == pytest.approx(np.dot(w, g.sg(d, axis, lam) * (d @ axis >= 0)), rel=1e-3)


def test_sg_integral_small_and_large_lambda():
    # lam -> 0: 4 pi (1 - lam + 2 lam^2 / 3 - lam^3 / 3 ...) to full precision (1 - e^-2lam by expm1).
    for lam in [1e-3, 1e-8, 1e-300]:
        assert g.sg_integral(lam) == pytest.approx(4 * np.pi * (1 - lam + 2 * lam**2 / 3 - lam**3 / 3), rel=1e-12)
    assert g.sg_integral(0.0) == pytest.approx(4 * np.pi, rel=1e-15)
    # lam large: 2 pi / lam exactly (e^-2lam underflows harmlessly), no overflow anywhere.
    for lam in [1e4, 1e8, 1e300]:
        assert g.sg_integral(lam) == pytest.approx(2 * np.pi / lam, rel=1e-15)
    assert g.sg_hemisphere_integral(1e-3) == pytest.approx(2 * np.pi * (1 - 5e-4 + 1e-6 / 6 - 1e-9 / 24), rel=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-7, 0.4, 2.0, np.pi - 1e-6, np.pi])
@pytest.mark.parametrize("lams", [(1e-3, 2.0), (5.0, 5.0), (300.0, 40.0), (1e4, 1e4)])
def test_sg_product_pointwise(angle, lams):
    """G1 G2 = G(xi_m, lam_m, mu_m) at random directions (relative, where representable)."""
    l1, l2 = lams
    a1, a2 = rotated_pair(angle)
    axis, lam_m, mu_m = g.sg_product(a1, l1, 2.0, a2, l2, 0.5)
    assert np.isfinite(lam_m) and np.isfinite(mu_m) and mu_m <= 1.0 + 1e-15
    assert np.linalg.norm(axis) == pytest.approx(1.0, abs=1e-14)
    rng = np.random.default_rng(RNG_SEED)
    v = unit(rng.normal(size=(200, 3)))
    v = np.concatenate([v, [a1, a2, axis]])
    lhs = g.sg(v, a1, l1, 2.0) * g.sg(v, a2, l2, 0.5)
    rhs = g.sg(v, axis, lam_m, mu_m)
    # Compare logs where values are representable: exponent differences are exact up to rounding.
    ok = lhs > 1e-280
    assert np.allclose(rhs[ok], lhs[ok], rtol=1e-9 * max(1.0, (l1 + l2) / 100), atol=0)
    assert np.all(rhs[~ok] < 1e-270)


def test_sg_product_nearly_opposite_lobes_exact_parameters():
    """lam1 = lam2 = 1e3, axes pi - 1e-6 apart: lam_m = 2 lam sin(delta / 2) = 1e-3 exactly; the
    textbook sqrt(l1^2 + l2^2 + 2 l1 l2 cos) loses four digits here, the stable form none."""
    delta = 1e-6
    a1, a2 = rotated_pair(np.pi - delta)
    _, lam_m, mu_m = g.sg_product(a1, 1e3, 1.0, a2, 1e3, 1.0)
    exact = 2e3 * math.sin(delta / 2)
    assert lam_m == pytest.approx(exact, rel=1e-9)
    naive = math.sqrt(2e6 + 2e6 * float(a1 @ a2))
    assert abs(naive / exact - 1) > 1e-6  # the failure the stable form avoids
    assert mu_m == pytest.approx(math.exp(exact - 2e3), rel=1e-9)
    # exactly opposite, equal sharpness: a constant lobe
    _, lam0, mu0 = g.sg_product(a1, 7.0, 1.0, -a1, 7.0, 1.0)
    assert lam0 == 0.0 and mu0 == pytest.approx(math.exp(-14.0), rel=1e-14)
    assert g.sg_inner_product(a1, 7.0, 1.0, -a1, 7.0, 1.0) == pytest.approx(4 * np.pi * math.exp(-14.0), rel=1e-14)


def test_sg_product_nearly_aligned_amplitude():
    """mu_m = exp(lam_m - l1 - l2) for axes 1e-6 apart at lam = 1e4: the exponent is
    -l1 l2 |xi1 - xi2|^2 / (l1 + l2 + lam_m) = -2.5e-5 (l1 = l2), kept to full precision."""
    a1, a2 = rotated_pair(1e-6)
    _, lam_m, mu_m = g.sg_product(a1, 1e4, 1.0, a2, 1e4, 1.0)
    chord2 = (2 * math.sin(0.5e-6)) ** 2
    assert math.log(mu_m) == pytest.approx(-1e8 * chord2 / (2e4 + lam_m), rel=1e-9)
    assert lam_m == pytest.approx(2e4 * math.cos(0.5e-6), rel=1e-15)


@pytest.mark.parametrize("angle", [0.0, 0.7, 2.5, np.pi - 1e-4])
@pytest.mark.parametrize("lams", [(1e-3, 1e-3), (0.5, 3.0), (30.0, 300.0), (1e4, 2e3)])
def test_sg_inner_product_against_quadrature(angle, lams):
    l1, l2 = lams
    a1, a2 = rotated_pair(angle)
    axis, lam_m, _ = g.sg_product(a1, l1, 1.3, a2, l2, 0.8)
    d, w = lobe_rule(axis, lam_m, n_beta=96)
    brute = np.dot(w, g.sg(d, a1, l1, 1.3) * g.sg(d, a2, l2, 0.8))
    closed = g.sg_inner_product(a1, l1, 1.3, a2, l2, 0.8)
    assert np.isfinite(closed) and closed >= 0  # 0 where the true value underflows (lams3 at 2.5)
    assert closed == pytest.approx(brute, rel=1e-10, abs=1e-300)


# --------------------------------------------------------------------------- SG x clamped cosine


def cosine_brute(t, lam):
    """E(t; lam) by 2-D quadrature in the frame of n over the upper hemisphere only (no kink):
    z = v.n by panels graded at the peak z = t, azimuth by panels graded at 0."""
    z, wz = g.panel_rule(g.graded_breaks(0.0, 1.0, min(max(t, 0.0), 1.0), 1 / math.sqrt(lam)), 16)
    st = math.sqrt(max(0.0, 1 - t * t))
    width = 1 / math.sqrt(lam * max(st, 1e-12))
    b, wb = g.panel_rule(g.graded_breaks(-np.pi, np.pi, 0.0, width), 16)
    sz = np.sqrt(1 - z * z)
    dot = t * z[:, None] + st * sz[:, None] * np.cos(b)[None, :]
    return float(np.einsum("i,j,ij->", wz * z, wb, np.exp(lam * (dot - 1))))


@pytest.mark.parametrize("lam", [1e-3, 1.0, 30.0, 1e4])
@pytest.mark.parametrize("t", [-0.9, -0.2, 0.0, 0.3, 1.0])
def test_sg_cosine_exact_against_quadrature(t, lam):
    exact = float(g.sg_cosine_exact(t, lam))
    brute = cosine_brute(t, lam)
    assert np.isfinite(exact)
    assert exact == pytest.approx(brute, rel=1e-9, abs=1e-300)


def test_sg_cosine_ends_and_odd_part():
    lams = np.array([1e-3, 0.3, 1.0, 4.0, 50.0, 1e4])
    up, down, zero = g.sg_cosine_ends(lams)
    assert np.allclose(up, g.sg_cosine_exact(1.0, lams), rtol=1e-12)
    assert np.allclose(down, g.sg_cosine_exact(-1.0, lams), rtol=1e-12, atol=1e-300)
    # E(0) = 2 pi e^-lam I_1(lam) / lam uses the A&S polynomial above 3.75 (6e-7 relative)
    assert np.allclose(zero, g.sg_cosine_exact(0.0, lams), rtol=1e-6)
    # E(t) - E(-t) = t C1 exactly
    for lam in [1e-3, 2.0, 400.0]:
        t = np.array([0.1, 0.5, 0.9])
        odd = 0.5 * (g.sg_cosine_exact(t, lam) - g.sg_cosine_exact(-t, lam))
        assert np.allclose(g.sg_cosine_odd(t, lam), odd, rtol=1e-11)


COSINE_T = np.linspace(-1.0, 1.0, 81)
COSINE_LAMBDAS = 10.0 ** np.linspace(-3, 4, 22)


def cosine_errors(approx):
    """(max, RMS) over lam of the error relative to E(1; lam), the largest value at each lam."""
    worst, rms = [], []
    for lam in COSINE_LAMBDAS:
        exact = g.sg_cosine_exact(COSINE_T, lam)
        err = (approx(COSINE_T, lam) - exact) / exact.max()
        worst.append(np.abs(err).max())
        rms.append(math.sqrt(np.mean(err * err)))
    return np.array(worst), np.array(rms)


@pytest.fixture(scope="module")
def cosine_measured():
    return {"seed": cosine_errors(g.sg_cosine_seed), "closed": cosine_errors(g.sg_cosine_closed)}


def test_sg_cosine_closed_form_error_bound(cosine_measured):
    """The derived closed form: error <= 0.45 % of E(1) everywhere (measured 0.40 %), RMS <= 0.3 % (0.24 %)."""
    worst, rms = cosine_measured["closed"]
    assert worst.max() <= 4.5e-3
    assert rms.max() <= 3e-3
    # exact at both ends of the range: broad lobes (lam -> 0) and the axis on the normal
    assert worst[0] < 1e-6
    assert np.allclose(g.sg_cosine_closed(1.0, COSINE_LAMBDAS), g.sg_cosine_exact(1.0, COSINE_LAMBDAS), rtol=1e-6)


def test_sg_cosine_seed_error_is_what_docs_say(cosine_measured):
    """Rows 'seed single SG' and 'closed form' of the doc's SG x cosine table: max and RMS
    (percent of E(1), over lam in [1e-3, 1e4] and t in [-1, 1]) match a fresh measurement."""
    rows = {r[0]: r for r in doc_table("### SG × clamped cosine: measured error")}
    for key, name in [("seed", "seed single SG"), ("closed", "closed form (3.3)")]:
        worst, rms = cosine_measured[key]
        doc_max, doc_rms = float(rows[name][1].rstrip(" %")), float(rows[name][2].rstrip(" %"))
        assert 100 * worst.max() == pytest.approx(doc_max, abs=0.006)
        assert 100 * rms.max() == pytest.approx(doc_rms, abs=0.006)
    assert cosine_measured["seed"][0].max() > 20 * cosine_measured["closed"][0].max()


@pytest.mark.parametrize("t", [-1.0, -0.6, -0.1])
@pytest.mark.parametrize("lam", [1e-3, 3.0, 1e4])
def test_sg_cosine_axis_below_horizon(t, lam):
    """Lobe axis below the receiver's horizon: the closed form stays finite, >= 0 and within
    0.45 % of E(1) of the exact value; the seed's approximation stays finite."""
    exact = float(g.sg_cosine_exact(t, lam))
    closed = float(g.sg_cosine_closed(t, lam))
    top = float(g.sg_cosine_exact(1.0, lam))
    assert np.isfinite(closed) and closed >= 0
    assert abs(closed - exact) <= 4.5e-3 * top
    assert np.isfinite(g.sg_cosine_seed(t, lam))


# --------------------------------------------------------------------------- the exact ISG


@pytest.mark.parametrize("lam", LAMBDAS)
def test_isg_exact_identities(lam):
    th = np.array([0.0, 0.7, np.pi / 2, 2.0, np.pi])
    ph = np.array([0.0, 0.4, np.pi / 2, np.pi, 4.0, 2 * np.pi])
    s = g.isg_exact_grid(lam, th, ph)
    assert np.allclose(s, g.isg_exact_grid(lam, th, ph, nodes=20), atol=1e-13)
    assert s[-1, 3] == pytest.approx(1.0, abs=1e-12)  # S(pi, pi) = H: the normaliser
    assert s[2, 3] == pytest.approx(0.5, abs=1e-12) and s[-1, 2] == pytest.approx(0.5, abs=1e-12)
    assert s[-1, -1] == pytest.approx(1 + math.exp(-lam), abs=1e-12)  # whole sphere / H
    assert np.all(s[0] == 0) and np.all(s[:, 0] == 0)
    # symmetry theta -> pi - theta: S(pi - t, p) = S(pi, p) - S(t, p)
    assert np.allclose(g.isg_exact_grid(lam, np.pi - th, ph), s[-1] - s, atol=1e-12)


def test_isg_exact_broad_lobe_limit():
    """lam -> 0: the integrand is sin(theta'), S_hat -> (1 - cos theta) phi / (2 pi) (+ O(lam))."""
    th, ph = np.linspace(0, np.pi, 13), np.linspace(0, 2 * np.pi, 25)
    s = g.isg_exact_grid(1e-6, th, ph)
    assert np.allclose(s, np.outer(1 - np.cos(th), ph) / (2 * np.pi), atol=1e-5)


@pytest.mark.parametrize("lam", [0.3, 20.0, 2000.0])
def test_isg_patch_against_direct_quadrature(lam):
    """A patch by the four-corner difference of S_hat equals a plain tensor Gauss-Legendre
    integral of the SG over it (an independent quadrature)."""
    w = min(1 / math.sqrt(lam), 0.5)  # the patch stays inside [0, pi]^2
    t0, t1, p0, p1 = np.pi / 2 - 0.3 * w, np.pi / 2 + 1.1 * w, np.pi / 2 - 2 * w, np.pi / 2 + 0.5 * w
    x, wx = np.polynomial.legendre.leggauss(60)
    t = t0 + (x + 1) * (t1 - t0) / 2
    p = p0 + (x + 1) * (p1 - p0) / 2
    f = np.exp(lam * (np.outer(np.sin(t), np.sin(p)) - 1)) * np.sin(t)[:, None]
    direct = (t1 - t0) * (p1 - p0) / 4 * (wx @ f @ wx)
    assert g.patch_integral(g.isg_exact, t0, t1, p0, p1, lam) == pytest.approx(direct, rel=1e-11)
    via_table = g.patch_integral(g.isg_eval, t0, t1, p0, p1, lam)
    assert abs(via_table - direct) <= 4 * 5e-3 * g.sg_hemisphere_integral(lam)


# --------------------------------------------------------------------------- seed fit and table evaluation

FIT_TH = np.linspace(0, np.pi, 91)
FIT_PH = np.linspace(0, np.pi, 91)  # the seed's domain: the lobe's front hemisphere
EVAL_PH = np.linspace(0, 2 * np.pi, 121)  # the evaluation covers the whole sphere


def seed_fit_error(lam):
    exact = g.isg_exact_grid(lam, FIT_TH, FIT_PH)
    return np.abs(g.isg_seed_fit(FIT_TH[:, None], FIT_PH[None, :], lam) - exact).max()


def eval_error(lam):
    exact = g.isg_exact_grid(lam, FIT_TH, EVAL_PH)
    return np.abs(g.isg_eval(FIT_TH[:, None], EVAL_PH[None, :], lam) - exact).max()


def test_isg_error_table_is_what_docs_say():
    """The doc's table 'ISG: max abs error by lam' lists, per lam, the seed fit's and the
    table evaluation's max |error| against the exact S_hat: fresh measurements must match
    (to the printed rounding), and the seed's own figures (0.0966 at lam = 100, 0.0251 at
    1000, its Fig. 3) are reproduced within 10 %."""
    rows = doc_table("### ISG: max abs error by λ")
    assert len(rows) >= 8
    for lam_s, fit_s, eval_s in (r[:3] for r in rows):
        lam = float(lam_s)
        assert seed_fit_error(lam) == pytest.approx(float(fit_s), abs=6e-4, rel=0.01)
        assert eval_error(lam) <= max(float(eval_s) + 6e-4, 1e-4)
    assert seed_fit_error(100.0) == pytest.approx(0.0966, rel=0.1)
    assert seed_fit_error(1000.0) == pytest.approx(0.0251, rel=0.1)


def test_isg_eval_accurate_everywhere():
    """max |isg_eval - S_hat| <= 0.005 (the requirement: 0.01) over lam in [1e-3, 1e4]
    (on and between table rows, 16 per decade) and beyond the table's range, with
    theta in [0, pi] and phi in [0, 2 pi] (the back hemisphere included)."""
    lams = np.concatenate([10.0 ** (np.arange(-48, 65) / 16), [5e-4, 3e4, 1e6]])
    errs = np.array([eval_error(lam) for lam in lams])
    assert errs.max() <= 5e-3, (lams[errs.argmax()], errs.max())
    # the seed's fit, on its own domain, is far from that for broad lobes
    assert seed_fit_error(1.0) > 0.5


def test_isg_eval_limits_and_symmetry():
    table = g.isg_table()
    assert table.floats < 10_000  # four 57 x 33 tables: small enough for constant memory
    for lam in [1e-3, 2.0, 1e4]:
        assert g.isg_eval(np.pi, np.pi, lam) == pytest.approx(1.0, abs=1e-12)
        assert abs(g.isg_eval(0.0, 1.0, lam)) < 1e-15 and abs(g.isg_eval(1.0, 0.0, lam)) < 1e-15
        assert g.isg_eval(np.pi, 2 * np.pi, lam) == pytest.approx(1 + math.exp(-lam), abs=1e-12)
        th = np.linspace(0, np.pi, 31)
        vals = g.isg_eval(th, 2.0, lam)
        assert np.all(np.diff(vals) >= -1e-15)  # monotone in theta (a CDF)
