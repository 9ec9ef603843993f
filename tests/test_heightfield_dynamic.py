"""Dynamic terrain (docs/heightfield.md, "Dynamic terrain"): a local edit
(pn_heightfield_set_heights_region) makes the next frame rebuild only the
pyramid values the edit can change and search again only the (row group,
azimuth) lanes whose samples can read one of them. Every test compares the
partial update with a full recompute of the edited heights by a fresh
renderer, bit for bit: the partial update runs the same kernels on the same
inputs for everything it recomputes, and keeps the previous floats for what
cannot have changed, so any difference is a missed dependency. The mask's
conservativeness is also checked directly (what it kept does not change in
a full recompute), and a narrower mask (a build option) must be caught."""

from __future__ import annotations

import numpy as np
import pytest

import penumbra as pn
from penumbra import procedural
from penumbra.errors import InputError, PenumbraError
from penumbra.heightfield import make_terrain

from test_heightfield import Rig

N = 65                      # the field's size: big enough for far samples on coarse levels, quick on PoCL
HEIGHT_SCALE = 12.0
OUTPUTS = ("env", "total", "env_horizons", "normals")


@pytest.fixture(scope="module")
def env(ctx):
    return pn.EnvMap(ctx, procedural.sky(128, 64, sun_direction=(0.5, 0.5, 0.3)), face_size=32,
                     irradiance_face_size=32)


@pytest.fixture(scope="module")
def base_heights():
    return make_terrain("fbm", N, N, seed=4)


def crater(h: np.ndarray, cx: float, cz: float, radius: float, depth: float):
    """(x0, y0, block): the box of texels a bowl centred at (cx, cz) changes, and its new heights."""
    D, W = h.shape
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    q = ((i - cx) ** 2 + (j - cz) ** 2) / radius ** 2
    new = (h - np.where(q < 1.0, depth * (1.0 - q) ** 2, 0.0)).astype(np.float32)
    ys, xs = np.nonzero(new != h)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    return int(x0), int(y0), new[y0:y1, x0:x1]


def full(ctx, env, heights, lights=(), **params):
    """A fresh field, scene and renderer on `heights`: the full recompute, by default by the
    passes that keep nothing (partial_update = 0)."""
    rig = Rig(ctx, heights, env, height_scale=HEIGHT_SCALE, lights=lights)
    r = pn.Renderer(ctx, "heightfield", **{"partial_update": 0, **params})
    out = {w: r.read_output(rig.scene, w, rig.instance) for w in OUTPUTS}
    for li in range(len(lights)):
        out[f"light{li}"] = r.read_output(rig.scene, "light", rig.instance, li)
    return out


class Session:
    """One field and renderer that live through a sequence of local edits."""

    def __init__(self, ctx, env, heights, lights=(), **params):
        self.ctx, self.env, self.lights, self.params = ctx, env, lights, params
        self.h = heights.copy()
        self.rig = Rig(ctx, heights, env, height_scale=HEIGHT_SCALE, lights=lights)
        # a field keeps what partial updates need once it has had a local edit: one that
        # changes nothing, before the first frame
        self.rig.field.set_heights(heights[:1, :1], region=(0, 0))
        self.r = pn.Renderer(ctx, "heightfield", **params)
        self.frame()

    def frame(self) -> dict:
        keep = self.params.get("partial_update", 1)
        out = {w: self.r.read_output(self.rig.scene, w, self.rig.instance)
               for w in OUTPUTS + (("env_searched",) if keep else ())}
        for li in range(len(self.lights)):
            out[f"light{li}"] = self.r.read_output(self.rig.scene, "light", self.rig.instance, li)
        self.last = out
        return out

    def edit(self, x0: int, y0: int, block: np.ndarray) -> None:
        self.rig.field.set_heights(block, region=(x0, y0))
        self.h[y0:y0 + block.shape[0], x0:x0 + block.shape[1]] = block


def assert_same(partial: dict, reference: dict, what: str) -> None:
    for key, ref in reference.items():
        got = partial[key]
        bad = got != ref
        assert not bad.any(), (f"{what}: {key} differs from a full recompute at {int(bad.any(axis=-1).sum())} "
                               f"vertices (first at {np.argwhere(bad)[0][:2].tolist()}), max "
                               f"{float(np.abs(got - ref).max()):.3g}")


def check_edits(ctx, env, heights, edits, lights=(), expect_partial=True, **params):
    """Applies each edit (x0, y0, block) or a list of them before one frame, and compares
    the frame with a full recompute; checks that the mask only kept what a full recompute
    does not change. Returns the session's last outputs and the last full recompute."""
    s = Session(ctx, env, heights, lights, **params)
    previous = full(ctx, env, s.h, lights, **params)
    assert_same(s.last, previous, "first frame")
    for step in edits:
        for x0, y0, block in (step if isinstance(step, list) else [step]):
            s.edit(x0, y0, block)
        got = s.frame()
        ref = full(ctx, env, s.h, lights, **params)
        assert_same(got, ref, f"after edit {step if not isinstance(step, list) else 'group'}"[:60])
        if "env_searched" not in got:
            continue
        searched = got["env_searched"]
        if expect_partial:
            assert searched.mean() < 1.0, "no lane was kept: the update was not partial"
        # what the mask kept does not change in a full recompute: lanes, and the radiance of
        # vertices with every lane kept away from the edit (whose normals did not change)
        kept = searched == 0
        np.testing.assert_array_equal(ref["env_horizons"][kept], previous["env_horizons"][kept])
        still = kept.all(axis=-1) & (ref["normals"] == previous["normals"]).all(axis=-1)
        np.testing.assert_array_equal(ref["env"][still], previous["env"][still])
        previous = ref
    return s, previous


# ------------------------------------------------------------------ equal to a full recompute


def test_crater_at_the_centre(ctx, env, base_heights):
    c = 0.5 * (N - 1)
    s, _ = check_edits(ctx, env, base_heights, [crater(base_heights, c, c, 0.05 * (N - 1), 0.5)])
    # the pyramid mode's lanes that can change (bench/heightfield_dynamic.py): well under all of them
    assert s.last["env_searched"].mean() < 0.9


def test_crater_in_a_corner(ctx, env, base_heights):
    check_edits(ctx, env, base_heights, [crater(base_heights, 0.0, 0.0, 0.05 * (N - 1), 0.5)])


def test_crater_on_the_border(ctx, env, base_heights):
    check_edits(ctx, env, base_heights, [crater(base_heights, N - 1, 0.4 * (N - 1), 0.05 * (N - 1), 0.5),
                                         crater(base_heights, 0.3 * (N - 1), N - 1, 0.05 * (N - 1), 0.5)])


def test_one_texel(ctx, env, base_heights):
    check_edits(ctx, env, base_heights, [(17, 40, base_heights[40:41, 17:18] + np.float32(0.3)),
                                         (N - 1, N - 1, base_heights[N - 1:, N - 1:] - np.float32(0.2))])


def test_a_raised_peak_shadows_far_terrain(ctx, env, base_heights):
    """A tall peak near one border: its shadow reaches the far side of the field, through
    far samples on coarse levels; still the same floats as a full recompute."""
    j, i = np.mgrid[0:5, 0:5]
    peak = base_heights[30:35, 2:7] + np.float32(4.0) * np.exp(-((i - 2) ** 2 + (j - 2) ** 2) / 2.0).astype(np.float32)
    s, ref = check_edits(ctx, env, base_heights, [(2, 30, peak)])
    before = full(ctx, env, base_heights)
    moved = np.abs(ref["env_horizons"] - before["env_horizons"]).max(axis=-1) > 1e-3
    assert moved[:, 40:].any(), "the peak should change horizons far from it (the test's premise)"


def test_repeated_edits_with_and_without_frames_between(ctx, env, base_heights):
    r = 0.05 * (N - 1)
    edits = [crater(base_heights, 20, 20, r, 0.4), crater(base_heights, 44, 30, r, 0.4),
             # two edits before one frame: their boxes are joined (one box: kept near each other here)
             [crater(base_heights, 10, 50, r, 0.3), crater(base_heights, 16, 55, r, 0.3)],
             # the same place again, back up
             (20 - 3, 20 - 3, base_heights[17:24, 17:24] + np.float32(0.1))]
    check_edits(ctx, env, base_heights, edits)


def test_lights_too(ctx, env, base_heights):
    lights = [[3.0, 4.0, -2.0, 0.5, 30.0, 25.0, 20.0], [-10.0, 2.0, 8.0, 0.3, 10.0, 10.0, 40.0]]
    check_edits(ctx, env, base_heights, [crater(base_heights, 32, 32, 3.2, 0.5)], lights=lights)
    check_edits(ctx, env, base_heights, [crater(base_heights, 40, 20, 3.2, 0.5)], lights=lights[:1],
                light_visibility=0)


def test_exact_horizon_mode(ctx, env, base_heights):
    s, _ = check_edits(ctx, env, base_heights, [crater(base_heights, 32, 32, 3.2, 0.5)], exact_horizon=1,
                       azimuths=16)
    # the exact march's lanes meet a 7-texel box: few of them, and some vertices keep all
    assert s.last["env_searched"].mean() < 0.3
    assert (s.last["env_searched"] == 0).all(axis=-1).any()


def test_other_settings(ctx, env, base_heights):
    check_edits(ctx, env, base_heights, [crater(base_heights, 32, 32, 3.2, 0.5)], level_step=2, level_offset=4,
                azimuths=12, bands=4, exact_unoccluded=0)
    # coarser levels read nearer (a smaller level offset): on this small field every
    # receiver's coarse levels change, so every lane is searched again; still equal
    check_edits(ctx, env, base_heights, [crater(base_heights, 32, 32, 3.2, 0.5)], expect_partial=False,
                level_step=2, level_offset=2.5, azimuths=12)


def test_interpolating_reconstruction_recomputes_all(ctx, env, base_heights):
    """The interpolating levels are solved along whole rows and columns: any edit changes
    every value, so the update is a full one (and equal to it)."""
    s, _ = check_edits(ctx, env, base_heights, [crater(base_heights, 32, 32, 3.2, 0.5)], expect_partial=False,
                       reconstruction=1)
    assert (s.last["env_searched"] == 1).all()


def test_nothing_changed_and_full_changes(ctx, env, base_heights):
    s = Session(ctx, env, base_heights)
    first = s.last
    # a region edit that writes the same heights: the lanes that read its box are searched
    # again (it may have changed), with the same result; the others are kept
    s.edit(5, 5, base_heights[5:9, 5:9].copy())
    again = s.frame()
    assert_same(again, {k: first[k] for k in OUTPUTS}, "same heights")
    assert 0 < again["env_searched"].mean() < 1
    # a full set_heights, new settings: full passes
    s.rig.field.set_heights(s.h)
    assert (s.frame()["env_searched"] == 1).all()
    s.edit(5, 5, base_heights[5:9, 5:9] + np.float32(0.5))
    assert s.frame()["env_searched"].mean() < 1
    s.r.set(bands=5)
    got = s.frame()
    assert (got["env_searched"] == 1).all()
    assert_same(got, full(ctx, env, s.h, bands=5), "new settings")


def test_partial_update_off(ctx, env, base_heights):
    check_edits(ctx, env, base_heights, [crater(base_heights, 32, 32, 3.2, 0.5)], expect_partial=False,
                partial_update=0)
    rig = Rig(ctx, base_heights, env)
    with pytest.raises(PenumbraError, match="partial_update = 1"):
        pn.Renderer(ctx, "heightfield", partial_update=0).read_output(rig.scene, "env_searched", rig.instance)


# ------------------------------------------------------------------ the tests can fail


def test_a_narrower_mask_is_caught(base_heights):
    """Built with the taps' slack at -1 level cell (the mask misses the outer B-spline taps),
    the partial update must differ from a full recompute: the equality tests above can fail."""
    ctx = pn.Context("build_options=-DHF_TAP_SLACK=-1.0f")
    env = pn.EnvMap(ctx, procedural.sky(128, 64, sun_direction=(0.5, 0.5, 0.3)), face_size=32,
                    irradiance_face_size=32)
    with pytest.raises(AssertionError, match="differs from a full recompute|not equal"):
        check_edits(ctx, env, base_heights, [crater(base_heights, 32, 32, 3.2, 0.5)])


# ------------------------------------------------------------------ bad regions


def test_bad_regions_are_refused(ctx, env, base_heights):
    rig = Rig(ctx, base_heights, env, height_scale=HEIGHT_SCALE)
    with pytest.raises(InputError, match="not inside the 65 x 65 field"):
        rig.field.set_heights(np.zeros((4, 4), np.float32), region=(63, 0))
    with pytest.raises(InputError, match="not inside"):
        rig.field.set_heights(np.zeros((4, 4), np.float32), region=(-1, 0))
    with pytest.raises(InputError, match="not inside"):
        rig.field.set_heights(np.zeros((0, 4), np.float32), region=(0, 0))
    with pytest.raises(InputError, match="2D array"):
        rig.field.set_heights(np.zeros(4, np.float32), region=(0, 0))
    bad = np.zeros((3, 3), np.float32)
    bad[1, 2] = np.nan
    with pytest.raises(PenumbraError, match="1 non-finite.*row 11, column 22"):
        rig.field.set_heights(bad, region=(20, 10))
    # refused edits leave the field as it was: a frame equals the original's
    r = pn.Renderer(ctx, "heightfield")
    np.testing.assert_array_equal(r.read_output(rig.scene, "env", rig.instance), full(ctx, env, base_heights)["env"])


def test_more_edits_than_the_field_remembers(ctx, env, base_heights):
    """The field keeps the boxes of its last 16 region commits: a renderer 16 commits behind
    still updates in part, one 17 behind recomputes all; both equal a full recompute."""
    for commits, partial in ((16, True), (17, False)):
        s = Session(ctx, env, base_heights)
        for q in range(commits):
            s.edit(30 + q % 3, 30, s.h[30:32, 30 + q % 3:32 + q % 3] + np.float32(0.01))
        got = s.frame()
        assert_same(got, full(ctx, env, s.h), f"{commits} commits behind")
        assert (got["env_searched"].mean() < 1.0) == partial


def test_fields_without_local_edits_keep_nothing(ctx, env, base_heights):
    """A field that never had a region edit keeps nothing (its frames cost as before); its
    first local edit gives a full frame that starts keeping, the next one a partial update."""
    rig = Rig(ctx, base_heights, env, height_scale=HEIGHT_SCALE)
    r = pn.Renderer(ctx, "heightfield")
    assert (r.read_output(rig.scene, "env_searched", rig.instance) == 1).all()
    h = base_heights.copy()
    for step, partial in ((0, False), (1, True)):
        h[20:23, 20 + step:23 + step] += np.float32(0.2)
        rig.field.set_heights(h[20:23, 20 + step:23 + step], region=(20 + step, 20))
        assert (r.read_output(rig.scene, "env_searched", rig.instance).mean() < 1.0) == partial
        assert_same({"env": r.read_output(rig.scene, "env", rig.instance)}, {"env": full(ctx, env, h)["env"]},
                    f"edit {step}")
