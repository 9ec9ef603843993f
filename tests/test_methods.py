"""penumbra.methods: the library's method metadata as Python reads it, the
per-technique modules, `penumbra methods [--json]`, the scene file's [render]
checks against the metadata, and the bindings that ask the library instead of
restating its rules (lobe names, the uniform-scale test, FIV defaults)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import penumbra
from penumbra import _native, methods, procedural
from penumbra.cli import main
from penumbra.core import LOBES, uniform_scale
from penumbra.errors import InputError
from penumbra.methods.fiv import FivOptions, bake_values
from penumbra.scenefile import parse_scene


def test_catalog_is_the_librarys_method_list():
    specs = methods.catalog()
    assert tuple(specs) == _native.methods()
    for name, m in specs.items():
        assert m.name == name and m.summary and m.doc_page.startswith("docs/") and m.stage
        assert m.inputs <= set(_native.INPUTS)
        for p in m.params:
            assert p.type in ("int", "float") and p.stage in methods.STAGES
            assert p.min <= p.default <= p.max and p.doc
            assert isinstance(p.default, int) == (p.type == "int")
    with pytest.raises(InputError, match="unknown method 'nope'.*fiv"):
        methods.spec("nope")


def test_every_method_has_its_module():
    for name in methods.catalog():
        t = methods.technique(name)
        assert t.name == name and type(t).__module__ == f"penumbra.methods.{name}"
    assert set(methods.interactive()) == {"unshadowed", "fiv", "heightfield", "depthmap", "isg"}


def test_methods_json_lists_everything_from_the_library(capsys):
    assert main(["methods", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)["methods"]
    specs = methods.catalog()
    assert [m["name"] for m in data] == list(specs)
    for m in data:
        s = specs[m["name"]]
        assert m["summary"] == s.summary and set(m["inputs"]) == set(s.inputs) and m["doc_page"] == s.doc_page
        assert [p["name"] for p in m["parameters"]] == [p.name for p in s.params]
        for p in m["parameters"]:
            assert set(p) == {"name", "type", "stage", "default", "min", "max", "unit", "doc"}
        assert [o["name"] for o in m["outputs"]] == [o.name for o in s.outputs]
        assert isinstance(m["interactive"], bool)
    fiv = next(m for m in data if m["name"] == "fiv")
    bake = {p["name"]: p["default"] for p in fiv["parameters"] if p["stage"] == "bake"}
    d = _native.lib.pn_fiv_options_default()
    assert bake == {name: pytest.approx(getattr(d, name)) for name, _ in _native.FivOptions._fields_}
    hf = next(m for m in data if m["name"] == "heightfield")
    assert "normals" in [o["name"] for o in hf["outputs"]] and "heightfield" in hf["inputs"]


def test_methods_text_and_render_help_name_every_method(capsys):
    assert main(["methods"]) == 0
    out = capsys.readouterr().out
    for name, m in methods.catalog().items():
        assert f"{name}: {m.summary}" in out
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    help_text = "".join(capsys.readouterr().out.split())  # argparse wraps (also at hyphens)
    for name, m in methods.catalog().items():
        assert "".join(f"{name}: {m.summary}".split()) in help_text


# ---------------------------------------------------------------- [render] against the metadata


def render_error(table: dict) -> str:
    with pytest.raises(InputError) as info:
        parse_scene({"render": table})
    return str(info.value)


def test_render_table_takes_the_methods_renderer_parameters():
    r = parse_scene({"render": {"method": "fiv", "overlap": 0, "cull_threshold": 0.01, "background": False}}).render
    assert r == {"method": "fiv", "overlap": 0, "cull_threshold": 0.01, "background": 0}
    assert parse_scene({"render": {"face_size": 8, "method": "reference"}}).render["face_size"] == 8
    assert parse_scene({"render": {"background": 0}}).render == {"background": 0}  # the default method


@pytest.mark.parametrize("table, words", [
    ({"method": "nope"}, ["[render] method", "is not one of", "fiv"]),
    ({"method": "fiv", "face_size": 8}, ["[render] face_size", "bake option of fiv", "[fiv]"]),
    ({"method": "fiv", "samples": [8, 5, 4]}, ["[render] samples", "[fiv]"]),
    ({"method": "fiv", "azimuths": 8}, ["[render] has unknown key azimuths", "method fiv", "overlap"]),
    ({"overlap": 1}, ["unknown key overlap", "method unshadowed", "background"]),
    ({"method": "fiv", "overlap": 3}, ["[render] overlap", "[0, 2]"]),
    ({"method": "fiv", "overlap": 1.5}, ["[render] overlap", "integer"]),
    ({"method": "heightfield", "level_offset": "x"}, ["[render] level_offset", "number"]),
    ({"method": "floor", "background": 1}, ["method floor", "none"]),
])
def test_render_table_errors_name_the_key(table, words):
    msg = render_error(table)
    for w in words:
        assert w in msg, msg


def test_flat_render_overrides_split_by_stage():
    fiv = methods.technique("fiv")
    renderer, bake = fiv.split_params({"samples": [8, 5, 4], "overlap": 0, "face_size": 8})
    assert renderer == {"overlap": 0} and bake == {"samples": [8, 5, 4], "face_size": 8}
    with pytest.raises(InputError, match="unknown parameter 'azimuths'"):
        fiv.split_params({"azimuths": 8})
    with pytest.raises(InputError, match="no bake parameters"):
        methods.technique("unshadowed").prepare(None, {"samples": 1})


# ---------------------------------------------------------------- asked of the library


def test_fiv_options_come_from_the_metadata():
    o = FivOptions()
    assert o.values == {p.name: p.default for p in methods.spec("fiv").params_of("bake")}
    assert o.paper_samples == (o.phi, o.theta, o.radii) and o.samples == (o.theta, o.phi, o.radii)
    assert FivOptions.from_paper((64, 33, 30)).samples == (33, 64, 30)
    assert FivOptions(precision="float32").values["precision"] == 0
    with pytest.raises(InputError, match=r"--radii = 1 is outside \[2, 256\]"):
        bake_values({"radii": 1}, lambda k: f"--{k}")
    with pytest.raises(InputError, match=r"samples\[2\] \(radii\)"):
        bake_values({"samples": [8, 5, 1]})
    assert FivOptions(face_size=8) == FivOptions(face_size=8) != FivOptions()


def test_lobe_names_are_the_librarys():
    assert LOBES == _native.lobes() == ("phong", "blinn_phong", "ggx", "ashikhmin_shirley")
    from penumbra.brdf import LOBES as FLOAT64_LOBES
    assert FLOAT64_LOBES == LOBES  # the float64 model knows every lobe, in the same order


def test_uniform_scale_is_the_librarys_test():
    t = np.eye(4)
    t[:3, :3] *= 1.7
    t[:3, 3] = (1, 2, 3)
    assert uniform_scale(t) == pytest.approx(1.7)
    for linear in (np.diag([1.0, 1.0, -1.0]), np.diag([1.0, 2.0, 1.0]),
                   np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])):
        t = np.eye(4)
        t[:3, :3] = linear
        assert uniform_scale(t) == 0.0


def test_mesh_geometry_reads_back_what_was_given(ctx):
    s = procedural.sphere(subdivisions=1)
    v, f, n = penumbra.Mesh(ctx, s.vertices, s.faces, s.normals).geometry()
    np.testing.assert_array_equal(v, s.vertices.astype(np.float32))
    np.testing.assert_array_equal(f, s.faces.astype(np.uint32))
    np.testing.assert_allclose(n, s.normals, atol=1e-7)
    assert penumbra.Mesh(ctx, s.vertices, s.faces).geometry()[2] is None


def test_attachments_follow_their_instances(ctx):
    from penumbra.methods.heightfield import HeightFieldHandle

    field = HeightFieldHandle(ctx, np.zeros((4, 5), np.float32))
    scene = penumbra.Scene(ctx)
    inst = scene.add(field.mesh())
    scene.attach(inst, field)
    assert scene.attachment(inst, HeightFieldHandle) is field
    scene.detach(inst, field)
    assert scene.attachment(inst, HeightFieldHandle) is None
    box = procedural.box()
    other = scene.add(penumbra.Mesh(ctx, box.vertices, box.faces))
    with pytest.raises(InputError):  # a height field on an instance whose mesh is not its grid
        scene.attach(other, field)
    scene.attach(inst, field)
    scene.remove(inst)
    assert scene.attachment(inst, HeightFieldHandle) is None


def test_fiv_fields_attach_by_mesh(ctx):
    from penumbra.methods.fiv import FivField, FivOptions, attach_by_mesh

    env = penumbra.EnvMap(ctx, procedural.constant(1.0, 16, 8), face_size=8, irradiance_face_size=8)
    s, b = procedural.sphere(subdivisions=1), procedural.box()
    sphere, box = penumbra.Mesh(ctx, s.vertices, s.faces), penumbra.Mesh(ctx, b.vertices, b.faces)
    field = FivField.bake(env, sphere, FivOptions(samples=(5, 8, 3), face_size=4, sun_supersampling=1))
    scene = penumbra.Scene(ctx)
    ids = [scene.add(sphere), scene.add(box), scene.add(sphere)]
    attach_by_mesh(scene, [field])
    assert [scene.attachment(i, FivField) is field for i in ids] == [True, False, True]
    attach_by_mesh(scene, [])
    assert all(scene.attachment(i, FivField) is None for i in ids)
