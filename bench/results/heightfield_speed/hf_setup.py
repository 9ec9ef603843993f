"""Set-up shared by the scripts of the height-field speed rounds in this folder (speed6_profile/,
speed7_search/, speed7_shade_profile/): a terrain bench scene built in a context of its own (a
kernel build per PENUMBRA_CL_BUILD_OPTIONS), the interleaved CPU-time profile of such builds, and
the float64 model's inputs (tests/heightfield64.py) for the early-exit models.

The scripts run from the repository root and import this module by its folder:
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
"""
import json
import os
import statistics
import sys
import time
from types import SimpleNamespace

TERRAIN_SCENES = ["bench/scenes/terrain_sunny.toml", "bench/scenes/terrain_overcast_light.toml"]


def terrain(scene, build_options=None, gbuffer=True):
    """``scene`` built in a new Context (``build_options``, when given, set as
    PENUMBRA_CL_BUILD_OPTIONS first: that context's kernel build), with its G-buffer drawn
    (unless ``gbuffer`` is False): ctx, desc, built, gb, img (None without the G-buffer) and the
    height field's field and instance."""
    from penumbra import GBuffer, Image
    from penumbra.core import Context
    from penumbra.methods.heightfield import fields
    from penumbra.render import build_scene
    from penumbra.scenefile import load_scene

    if build_options is not None:
        os.environ["PENUMBRA_CL_BUILD_OPTIONS"] = build_options
    ctx = Context()
    desc = load_scene(scene)
    built = build_scene(desc, ctx)
    gb = img = None
    if gbuffer:
        w, h = desc.camera.resolution
        gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
        built.scene.render_gbuffer(gb)
    field, inst = next(iter(fields(built).values()))
    return SimpleNamespace(ctx=ctx, desc=desc, built=built, gb=gb, img=img, field=field, inst=inst)


def profile(argv):
    """Interleaved CPU-time profile of heightfield variants in one process.
    usage: prof.py scene rounds frames 'name|buildopts|json params|what' ...   (what: frame or horizons)"""
    from penumbra import Renderer

    scene, rounds, frames = argv[0], int(argv[1]), int(argv[2])
    vs = []
    for spec in argv[3:]:
        name, opts, params, what = spec.split("|")
        t = terrain(scene, opts)
        r = Renderer(t.ctx, "heightfield", **json.loads(params or "{}"))
        if what == "frame":
            fn = lambda r=r, t=t: r.execute(t.built.scene, t.gb, t.img)
        else:
            fn = lambda r=r, t=t: r.read_output(t.built.scene, "env_horizons", t.inst)
        fn(); t.ctx.finish()
        vs.append(dict(name=name, fn=fn, ctx=t.ctx, cpu=[], wall=[]))
    print("load", os.getloadavg())
    for k in range(rounds):
        for v in (vs if k % 2 == 0 else vs[::-1]):
            for _ in range(frames):
                t0, c0 = time.perf_counter(), time.process_time()
                v["fn"](); v["ctx"].finish()
                v["cpu"].append(1000 * (time.process_time() - c0)); v["wall"].append(1000 * (time.perf_counter() - t0))
    base = statistics.median(vs[0]["cpu"])
    for v in vs:
        c = statistics.median(v["cpu"])
        print(f"{v['name']:30s} cpu {c:8.1f}  wall {statistics.median(v['wall']):8.1f}  base/this {base / c:5.2f}")
    print("load", os.getloadavg())


def model(scene):
    """The float64 model's inputs for ``scene``'s height field (tests/heightfield64.py, imported
    from tests/): its module t, heights H (D x W), spacing sx, sz, the 4-level pyramid ``levels``,
    n samples at distances d from levels L (level step 4, offset 4)."""
    import numpy as np
    from penumbra.scenefile import load_scene

    if "tests" not in sys.path:
        sys.path.insert(0, "tests")
    import heightfield64 as t

    hd = load_scene(scene).heightfields[0]
    H = np.asarray(hd.load().heights, np.float64) * hd.height_scale
    D, W = H.shape
    sx, sz = hd.size[0] / (W - 1), hd.size[1] / (D - 1)
    levels = t.pyramid(H, 4)
    n = len(levels)
    d, L = t.sample_plan(n, 4, 4.0, min(sx, sz))
    return SimpleNamespace(t=t, H=H, D=D, W=W, sx=sx, sz=sz, levels=levels, n=n, d=d, L=L)


def elevations(m, i, j, azimuths):
    """Per vertex (i, j) of the model ``m`` (model()), azimuth and sample: the elevation angle of
    the sample (omega, shape i.shape + (azimuths, n)), with the vertex's height per level (at_p)
    and the azimuths' steps (du, dv); and the B-spline's knot and mid values over omega."""
    import numpy as np

    t = m.t
    _, du, dv = t.azimuth_steps(azimuths, m.sx, m.sz)
    at_p = {k: t.level_sample(m.levels[k], m.W, m.D, i, j)[..., None] for k in set(m.L.tolist())}
    omega = np.empty(i.shape + (azimuths, m.n))
    for mm in range(m.n):
        k = m.L[mm]
        h = t.level_sample(m.levels[k], m.W, m.D, i[..., None] + m.d[mm] * du, j[..., None] + m.d[mm] * dv)
        omega[..., mm] = np.arctan((h - at_p[k]) / m.d[mm])
    ext = np.concatenate([omega[..., :1], omega], axis=-1)
    knots = (ext[..., :-2] + 4 * ext[..., 1:-1] + ext[..., 2:]) / 6
    mids = (ext[..., :-3] + 23 * ext[..., 1:-2] + 23 * ext[..., 2:-1] + ext[..., 3:]) / 48
    return SimpleNamespace(du=du, dv=dv, at_p=at_p, omega=omega, knots=knots, mids=mids)
