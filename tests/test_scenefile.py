"""The TOML scene contract (penumbra.scenefile): every key, defaults, path
resolution, error messages that name the table and key, object transforms and
``--set`` overrides. Pure Python: no device is needed."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from penumbra.errors import InputError
from penumbra.methods.fiv import FivTable
from penumbra.scenefile import (
    CameraDesc,
    EnvironmentDesc,
    ObjectDesc,
    SceneDescription,
    apply_overrides,
    default_scene_path,
    load_scene,
    parse_scene,
    read_toml,
)

# A scene that sets every documented key to a value other than its default.
FULL_TOML = """
[environment]
map = "maps/sky.exr"
intensity = 2.5
rotation_deg = -30.0
face_size = 48
irradiance_face_size = 12

[camera]
position = [1.0, 2.0, 3.0]
look_at = [0.0, 0.5, -1.0]
up = [0.0, 0.0, 1.0]
fov_deg = 55.5
resolution = [320, 200]

[render]
method = "unshadowed"
background = 0

[fiv]
samples = [64, 33, 30]
precision = "float32"
inner_radius = 0.3
error_target = 0.02
face_size = 16
sun_supersampling = 2
sun_threshold = 0.05
cache = "bakes"

[[object]]
name = "bunny"
mesh = "meshes/bunny.obj"
translate = [0.5, -1.0, 2.0]
rotate_deg = [10.0, 20.0, 30.0]
scale = [1.0, 2.0, 3.0]
albedo = [0.1, 0.2, 0.3]
specular = 0.25
shininess = 64.0
roughness = 0.5
lobe = "ggx"
occluder = false
crease_angle_deg = 30.0

[[object]]
name = "ball"
primitive = "sphere"
params = { radius = 0.5, subdivisions = 3 }
scale = 2
albedo = 0.4
lobe = "blinn_phong"
occluder = true
"""


def write_scene(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def scene_with(**tables) -> dict:
    """A minimal valid scene dict with some tables replaced or added."""
    data = {"camera": {"position": [0.0, 0.0, 5.0], "look_at": [0.0, 0.0, 0.0]}}
    data.update(tables)
    return data


def obj(**keys) -> dict:
    return {"name": "thing", "primitive": "box", **keys}


def parse_error(data: dict) -> str:
    with pytest.raises(InputError) as info:
        parse_scene(data)
    return str(info.value)


# ---------------------------------------------------------------- every key


def test_every_documented_key_parses(tmp_path):
    path = write_scene(tmp_path / "scene.toml", FULL_TOML)
    s = load_scene(path)
    assert isinstance(s, SceneDescription)
    assert s.source == str(path)

    e = s.environment
    assert e.map == str(tmp_path / "maps" / "sky.exr")
    assert (e.intensity, e.rotation_deg, e.face_size, e.irradiance_face_size) == (2.5, -30.0, 48, 12)
    assert e.params == {}

    c = s.camera
    assert c.position == (1.0, 2.0, 3.0)
    assert c.look_at == (0.0, 0.5, -1.0)
    assert c.up == (0.0, 0.0, 1.0)
    assert c.fov_deg == 55.5
    assert c.resolution == (320, 200)
    assert all(isinstance(v, int) for v in c.resolution)

    assert s.render == {"method": "unshadowed", "background": 0}

    assert [o.name for o in s.objects] == ["bunny", "ball"]
    b, ball = s.objects
    assert b.mesh == str(tmp_path / "meshes" / "bunny.obj") and b.primitive is None
    assert b.translate == (0.5, -1.0, 2.0)
    assert b.rotate_deg == (10.0, 20.0, 30.0)
    assert b.scale == (1.0, 2.0, 3.0)
    assert b.albedo == (0.1, 0.2, 0.3)
    assert (b.specular, b.shininess, b.roughness, b.lobe) == (0.25, 64.0, 0.5, "ggx")
    assert b.crease_angle_deg == 30.0 and ball.crease_angle_deg == 60.0  # the default

    assert ball.mesh is None and ball.primitive == "sphere"
    assert ball.params == {"radius": 0.5, "subdivisions": 3}
    assert ball.scale == (2.0, 2.0, 2.0)        # one number: uniform scale
    assert ball.albedo == (0.4, 0.4, 0.4)       # one number: grey
    assert ball.lobe == "blinn_phong"
    assert (b.occluder, b.is_occluder, ball.occluder, ball.is_occluder) == (False, False, True, True)

    f = s.fiv
    assert f.samples == (64, 33, 30) and all(isinstance(v, int) for v in f.samples)
    assert (f.precision, f.inner_radius, f.error_target, f.face_size, f.sun_supersampling, f.sun_threshold) == \
        ("float32", 0.3, 0.02, 16, 2, 0.05)
    assert f.cache == str(tmp_path / "bakes")   # relative to the scene file


def test_numbers_come_back_as_floats():
    s = parse_scene(scene_with(environment={"intensity": 2, "rotation_deg": 90},
                               object=[obj(translate=[1, 2, 3], scale=2, specular=1, shininess=10)]))
    assert type(s.environment.intensity) is float and type(s.environment.rotation_deg) is float
    o = s.objects[0]
    assert all(type(v) is float for v in o.translate + o.scale)
    assert type(o.specular) is float and type(o.shininess) is float


@pytest.mark.parametrize("name", ["sky", "constant", "directional", "area_lights"])
def test_procedural_maps_are_names_not_paths(tmp_path, name):
    path = write_scene(tmp_path / "s.toml", f'[environment]\nmap = "{name}"\n')
    assert load_scene(path).environment.map == name


def test_environment_params_are_kept_for_procedural_maps():
    s = parse_scene(scene_with(environment={"map": "constant", "params": {"value": [1.0, 0.5, 0.25], "width": 8}}))
    assert s.environment.map == "constant"
    assert s.environment.params == {"value": [1.0, 0.5, 0.25], "width": 8}


@pytest.mark.parametrize("primitive", ["sphere", "box", "plane", "torus", "cylinder", "cone", "torus_knot"])
def test_every_primitive_is_accepted(primitive):
    s = parse_scene(scene_with(object=[{"primitive": primitive}]))
    assert s.objects[0].primitive == primitive


@pytest.mark.parametrize("lobe", ["phong", "blinn_phong", "ggx"])
def test_every_lobe_is_accepted(lobe):
    assert parse_scene(scene_with(object=[obj(lobe=lobe)])).objects[0].lobe == lobe


def test_range_boundaries_that_are_allowed():
    s = parse_scene(scene_with(
        environment={"intensity": 0.0, "face_size": 1, "irradiance_face_size": 2},
        camera={"position": [0, 0, 1], "look_at": [0, 0, 0], "fov_deg": 179.9, "resolution": [1, 1]},
        object=[obj(albedo=[0.0, 1.0, 0.5], specular=1.0, shininess=0.0, roughness=1.0, scale=[-1, 2, 3])]))
    assert s.environment.intensity == 0.0
    assert s.camera.fov_deg == 179.9
    assert s.objects[0].roughness == 1.0
    assert s.objects[0].scale == (-1.0, 2.0, 3.0)  # a negative scale (mirror) is not flat


# ---------------------------------------------------------------- defaults


def test_defaults_of_an_empty_scene():
    s = parse_scene({})
    assert s.environment == EnvironmentDesc()
    e = s.environment
    assert (e.map, e.intensity, e.rotation_deg, e.face_size, e.irradiance_face_size, e.params) == \
        ("sky", 1.0, 0.0, 64, 32, {})
    assert s.camera == CameraDesc()
    c = s.camera
    assert (c.position, c.look_at, c.up, c.fov_deg, c.resolution) == \
        ((0.0, 2.0, 6.0), (0.0, 0.5, 0.0), (0.0, 1.0, 0.0), 40.0, (512, 512))
    assert s.objects == []
    assert s.render == {}
    assert s.source == "<dict>"
    assert s.fiv == FivTable()
    f = s.fiv
    assert (f.samples, f.precision, f.inner_radius, f.error_target, f.face_size, f.sun_supersampling,
            f.sun_threshold, f.cache) == ((32, 17, 15), "float16", 0.2, 0.01, 32, 4, 0.1, None)


def test_object_defaults():
    o = parse_scene(scene_with(object=[{"primitive": "sphere"}, {"primitive": "box"}])).objects
    assert [x.name for x in o] == ["object0", "object1"]  # unnamed objects are numbered
    d = o[0]
    assert d.params == {}
    assert (d.translate, d.rotate_deg, d.scale) == ((0.0, 0.0, 0.0),) * 2 + ((1.0, 1.0, 1.0),)
    assert (d.albedo, d.specular, d.shininess, d.roughness, d.lobe) == ((0.8, 0.8, 0.8), 0.0, 100.0, 0.3, "phong")
    np.testing.assert_array_equal(d.transform(), np.eye(4))


def test_default_scene_file_loads():
    s = load_scene(default_scene_path())
    assert s.environment.map == "sky"
    assert s.render.get("method") == "unshadowed"
    assert [o.name for o in s.objects] == ["ground", "sphere", "box", "torus", "knot"]
    assert all(o.primitive is not None and o.mesh is None for o in s.objects)
    # The shapes cast fiv shadows (the demo bakes them); the ground does not.
    assert [o.name for o in s.objects if o.is_occluder] == ["sphere", "box", "torus", "knot"]
    assert s.fiv.samples == (32, 17, 15)


# ---------------------------------------------------------------- fiv


def test_occluder_defaults_by_kind():
    o = parse_scene(scene_with(object=[{"name": "m", "mesh": "m.obj"}, {"name": "p", "primitive": "plane"},
                                       {"name": "b", "primitive": "box", "occluder": True},
                                       {"name": "n", "mesh": "n.obj", "occluder": False}])).objects
    assert [(x.name, x.occluder, x.is_occluder) for x in o] == \
        [("m", True, True), ("p", False, False), ("b", True, True), ("n", False, False)]
    # Built by hand, without parse_scene: None means "by kind".
    assert ObjectDesc(name="x", mesh="x.obj").is_occluder and not ObjectDesc(name="y", primitive="box").is_occluder


def test_fiv_bake_options_are_in_the_bindings_order():
    f = parse_scene({"fiv": {"samples": [64, 33, 30], "precision": "float32"}}).fiv
    opts = f.options
    assert opts.samples == (33, 64, 30)  # penumbra.FivOptions takes (theta, phi, radii), as pn_fiv_options
    assert (opts.theta, opts.phi, opts.radii) == (33, 64, 30)
    assert opts.precision_name == "float32" and opts.face_size == 32


def test_fiv_grid_by_name_or_samples():
    assert parse_scene({"fiv": {"theta": 9, "phi": 16, "radii": 5}}).fiv.samples == (16, 9, 5)
    assert "both set theta" in parse_error({"fiv": {"samples": [32, 17, 15], "theta": 9}})


def test_fiv_defaults_are_the_librarys():
    from penumbra.methods import spec

    f = parse_scene({}).fiv
    for p in spec("fiv").params_of("bake"):
        assert f.options.values[p.name] == p.default


def test_fiv_samples_boundaries_that_are_allowed():
    assert parse_scene({"fiv": {"samples": [4, 3, 2]}}).fiv.samples == (4, 3, 2)
    assert parse_scene({"fiv": {"samples": [2048, 1025, 2]}}).fiv.samples == (2048, 1025, 2)
    f = parse_scene({"fiv": {"error_target": 0.5, "sun_threshold": 1.0, "face_size": 256, "sun_supersampling": 8}}).fiv
    assert (f.error_target, f.sun_threshold, f.face_size * f.sun_supersampling) == (0.5, 1.0, 2048)


@pytest.mark.parametrize("fiv, key", [
    ({"sample": [32, 17, 15]}, "unknown key"),
    ({"samples": [32, 17]}, "samples"),
    ({"samples": "32x17x15"}, "samples"),
    ({"samples": [32, 17, 15.0]}, "samples[2] (radii)"),
    ({"samples": [3, 17, 15]}, "samples[0] (phi)"),
    ({"samples": [32, 2, 15]}, "samples[1] (theta)"),
    ({"samples": [32, 17, 1]}, "samples[2] (radii)"),
    ({"samples": [32, 17, 257]}, "samples[2] (radii)"),
    ({"precision": "half"}, "precision"),
    ({"precision": 16}, "precision"),
    ({"inner_radius": 0}, "inner_radius"),
    ({"inner_radius": 1.0}, "inner_radius"),
    ({"error_target": 0.0}, "error_target"),
    ({"error_target": 0.6}, "error_target"),
    ({"face_size": 0}, "face_size"),
    ({"face_size": 32.0}, "face_size"),
    ({"sun_supersampling": 17}, "sun_supersampling"),
    ({"sun_threshold": 0}, "sun_threshold"),
    ({"sun_threshold": 1.5}, "sun_threshold"),
    ({"cache": 3}, "cache"),
])
def test_fiv_table_errors_name_the_key(fiv, key):
    msg = parse_error({"fiv": fiv})
    assert "[fiv]" in msg and key in msg, msg


def test_fiv_must_be_a_table():
    assert "[fiv] must be a table" in parse_error({"fiv": [1, 2]})


@pytest.mark.parametrize("value", [1, "yes", None])
def test_occluder_must_be_a_boolean(value):
    msg = parse_error(scene_with(object=[obj(name="o", occluder=value)]))
    assert "[object 'o'] occluder" in msg and "true or false" in msg


def test_objects_sharing_a_mesh_may_differ_in_occluder():
    # Fields attach to instances, so an instance of an occluder's mesh may be a non-occluder.
    o = parse_scene(scene_with(object=[{"name": "a", "mesh": "m.obj"}, {"name": "b", "mesh": "m.obj",
                                                                       "occluder": False}])).objects
    assert [x.is_occluder for x in o] == [True, False] and o[0].geometry_key() == o[1].geometry_key()


def test_fiv_overrides_are_checked(tmp_path):
    path = write_scene(tmp_path / "s.toml", "[fiv]\nsamples = [32, 17, 15]\n")
    assert load_scene(path, ["fiv.samples=[8,5,4]", "fiv.precision=float32"]).fiv.samples == (8, 5, 4)
    with pytest.raises(InputError, match=r"\[fiv\] samples\[0\]"):
        load_scene(path, ["fiv.samples=[1,5,4]"])


# ---------------------------------------------------------------- paths


def test_relative_paths_resolve_against_the_scene_files_directory(tmp_path, monkeypatch):
    scene_dir = tmp_path / "project" / "scenes"
    text = ('[environment]\nmap = "../envmaps/sky.hdr"\n'
            '[[object]]\nname = "a"\nmesh = "meshes/a.obj"\n'
            '[[object]]\nname = "b"\nmesh = "./b.ply"\n')
    write_scene(scene_dir / "scene.toml", text)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the working directory must not matter
    for path in (scene_dir / "scene.toml", Path("../project/scenes/scene.toml")):
        s = load_scene(path)
        assert s.environment.map == str(tmp_path / "project" / "envmaps" / "sky.hdr")
        assert s.objects[0].mesh == str(scene_dir / "meshes" / "a.obj")
        assert s.objects[1].mesh == str(scene_dir / "b.ply")
        assert Path(s.environment.map).is_absolute()


def test_absolute_paths_are_kept(tmp_path):
    target = tmp_path / "abs" / "m.obj"
    path = write_scene(tmp_path / "x" / "s.toml", f'[[object]]\nmesh = "{target.as_posix()}"\n')
    assert load_scene(path).objects[0].mesh == str(target)


def test_parse_scene_resolves_against_base_dir(tmp_path):
    s = parse_scene({"object": [{"mesh": "m.obj"}], "environment": {"map": "e.exr"}}, base_dir=tmp_path)
    assert s.objects[0].mesh == str(tmp_path / "m.obj")
    assert s.environment.map == str(tmp_path / "e.exr")


def test_load_scene_does_not_check_that_files_exist(tmp_path):
    # Missing content files are reported when the scene is built, not parsed.
    path = write_scene(tmp_path / "s.toml", '[[object]]\nmesh = "nowhere.obj"\n')
    assert load_scene(path).objects[0].mesh == str(tmp_path / "nowhere.obj")


# ---------------------------------------------------------------- errors


@pytest.mark.parametrize("data, where, bad", [
    ({"lights": {}}, "[scene]", "lights"),
    ({"environment": {"colour": 1}}, "[environment]", "colour"),
    ({"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "focal": 35}}, "[camera]", "focal"),
    (scene_with(object=[obj(name="bunny", colour=[1, 0, 0])]), "[object 'bunny']", "colour"),
    (scene_with(object=[{"primitive": "box", "Scale": 2}]), "[object 'object0']", "Scale"),
])
def test_unknown_keys_are_named_with_their_table(data, where, bad):
    msg = parse_error(data)
    assert where in msg and "unknown key" in msg and bad in msg, msg


@pytest.mark.parametrize("data, table, key", [
    # environment
    ({"environment": {"map": 3}}, "environment", "map"),
    ({"environment": {"intensity": "bright"}}, "environment", "intensity"),
    ({"environment": {"intensity": True}}, "environment", "intensity"),
    ({"environment": {"intensity": float("nan")}}, "environment", "intensity"),
    ({"environment": {"rotation_deg": float("inf")}}, "environment", "rotation_deg"),
    ({"environment": {"rotation_deg": [90]}}, "environment", "rotation_deg"),
    ({"environment": {"face_size": 32.0}}, "environment", "face_size"),
    ({"environment": {"face_size": "64"}}, "environment", "face_size"),
    ({"environment": {"irradiance_face_size": True}}, "environment", "irradiance_face_size"),
    ({"environment": {"map": "sky", "params": [1, 2]}}, "environment", "params"),
    ({"environment": 5}, "environment", ""),
    # camera
    ({"camera": {"position": [0, 1]}}, "camera", "position"),
    ({"camera": {"position": "origin"}}, "camera", "position"),
    ({"camera": {"look_at": [0, "a", 0]}}, "camera", "look_at[1]"),
    ({"camera": {"up": [0, 1, 0, 0]}}, "camera", "up"),
    ({"camera": {"fov_deg": "wide"}}, "camera", "fov_deg"),
    ({"camera": {"resolution": 512}}, "camera", "resolution"),
    ({"camera": {"resolution": [64, 48, 3]}}, "camera", "resolution"),
    ({"camera": {"resolution": [64.0, 48]}}, "camera", "resolution[0]"),
    ({"camera": {"resolution": [64, "48"]}}, "camera", "resolution[1]"),
    ({"camera": []}, "camera", ""),
    # objects
    (scene_with(object=[obj(name="o", translate=[0, 0])]), "object 'o'", "translate"),
    (scene_with(object=[obj(name="o", translate=1.0)]), "object 'o'", "translate"),
    (scene_with(object=[obj(name="o", rotate_deg="x")]), "object 'o'", "rotate_deg"),
    (scene_with(object=[obj(name="o", scale="big")]), "object 'o'", "scale"),
    (scene_with(object=[obj(name="o", scale=[1, 2])]), "object 'o'", "scale"),
    (scene_with(object=[obj(name="o", albedo=[1, "red", 0])]), "object 'o'", "albedo[1]"),
    (scene_with(object=[obj(name="o", specular="shiny")]), "object 'o'", "specular"),
    (scene_with(object=[obj(name="o", shininess=[1])]), "object 'o'", "shininess"),
    (scene_with(object=[obj(name="o", roughness=None)]), "object 'o'", "roughness"),
    (scene_with(object=[obj(name="o", lobe=2)]), "object 'o'", "lobe"),
    (scene_with(object=[obj(name="o", lobe="lambert")]), "object 'o'", "lobe"),
    (scene_with(object=[obj(name="o", params=3)]), "object 'o'", "params"),
    (scene_with(object=[{"name": "o", "mesh": 7}]), "object 'o'", "mesh"),
    (scene_with(object=[{"name": "o", "primitive": "teapot"}]), "object 'o'", "primitive"),
    (scene_with(object=[{"name": 5, "primitive": "box"}]), "object '5'", "name"),
    # render
    ({"render": {"method": 1}}, "render", "method"),
    ({"render": "unshadowed"}, "render", ""),
])
def test_wrong_types_name_table_and_key(data, table, key):
    msg = parse_error(data)
    assert f"[{table}]" in msg, msg
    assert key in msg, msg


@pytest.mark.parametrize("data, table, key", [
    ({"camera": {"fov_deg": 0}}, "camera", "fov_deg"),
    ({"camera": {"fov_deg": 180}}, "camera", "fov_deg"),
    ({"camera": {"fov_deg": -10.0}}, "camera", "fov_deg"),
    ({"camera": {"resolution": [0, 48]}}, "camera", "resolution[0]"),
    ({"camera": {"resolution": [64, -1]}}, "camera", "resolution[1]"),
    ({"environment": {"intensity": -0.5}}, "environment", "intensity"),
    ({"environment": {"face_size": 0}}, "environment", "face_size"),
    ({"environment": {"face_size": 4096}}, "environment", "face_size"),
    ({"environment": {"irradiance_face_size": 1}}, "environment", "irradiance_face_size"),
    (scene_with(object=[obj(name="o", albedo=[0.5, 1.5, 0.5])]), "object 'o'", "albedo[1]"),
    (scene_with(object=[obj(name="o", albedo=1.01)]), "object 'o'", "albedo"),
    (scene_with(object=[obj(name="o", albedo=[0.5, 0.5, -0.1])]), "object 'o'", "albedo[2]"),
    (scene_with(object=[obj(name="o", roughness=0)]), "object 'o'", "roughness"),
    (scene_with(object=[obj(name="o", roughness=1.5)]), "object 'o'", "roughness"),
    (scene_with(object=[obj(name="o", specular=1.2)]), "object 'o'", "specular"),
    (scene_with(object=[obj(name="o", specular=-0.2)]), "object 'o'", "specular"),
    (scene_with(object=[obj(name="o", shininess=-1)]), "object 'o'", "shininess"),
    (scene_with(object=[obj(name="o", scale=0)]), "object 'o'", "scale"),
    (scene_with(object=[obj(name="o", scale=[1, 0.0, 1])]), "object 'o'", "scale"),
])
def test_out_of_range_values_name_table_and_key(data, table, key):
    msg = parse_error(data)
    assert f"[{table}] {key}" in msg, msg


def test_camera_looking_at_its_own_position():
    msg = parse_error({"camera": {"position": [1, 2, 3], "look_at": [1, 2, 3]}})
    assert "[camera]" in msg and "look_at" in msg


@pytest.mark.parametrize("o", [
    {"name": "both", "mesh": "a.obj", "primitive": "box"},
    {"name": "neither", "translate": [0, 0, 0]},
])
def test_exactly_one_of_mesh_and_primitive(o):
    msg = parse_error(scene_with(object=[o]))
    assert f"[object '{o['name']}']" in msg
    assert "mesh" in msg and "primitive" in msg


def test_environment_params_need_a_procedural_map():
    msg = parse_error({"environment": {"map": "file.exr", "params": {"width": 4}}})
    assert "[environment] params" in msg


def test_duplicate_object_names():
    msg = parse_error(scene_with(object=[obj(name="a"), obj(name="b"), obj(name="a")]))
    assert "unique" in msg and "a" in msg.split("repeated:")[1] and "b" not in msg.split("repeated:")[1]


def test_objects_must_be_an_array_of_tables():
    assert "[[object]]" in parse_error(scene_with(object={"name": "x", "primitive": "box"}))
    assert "[[object]] #1" in parse_error(scene_with(object=[obj(name="x"), "box"]))


def test_invalid_toml(tmp_path):
    path = write_scene(tmp_path / "bad.toml", "[camera]\nfov_deg = = 30\n")
    with pytest.raises(InputError, match="not valid TOML") as info:
        load_scene(path)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    path = tmp_path / "missing.toml"
    with pytest.raises(InputError, match="cannot read scene file") as info:
        load_scene(path)
    assert str(path) in str(info.value)
    with pytest.raises(InputError):
        read_toml(tmp_path)  # a directory is not a scene file either


def test_input_error_is_a_value_error():
    with pytest.raises(ValueError):
        parse_scene({"camera": {"fov_deg": 0}})


# ---------------------------------------------------------------- transforms


def rx(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def apply(m: np.ndarray, p) -> np.ndarray:
    return (m @ np.append(np.asarray(p, float), 1.0))[:3]


@pytest.mark.parametrize("rotate, point, image", [
    # single right-handed rotations
    ((90, 0, 0), (0, 1, 0), (0, 0, 1)),
    ((0, 90, 0), (0, 0, 1), (1, 0, 0)),
    ((0, 90, 0), (1, 0, 0), (0, 0, -1)),
    ((0, 0, 90), (1, 0, 0), (0, 1, 0)),
    # x first, then y: +y -> (x 90) +z -> (y 90) +x. The other order would give +z.
    ((90, 90, 0), (0, 1, 0), (1, 0, 0)),
    ((90, 90, 0), (1, 0, 0), (0, 0, -1)),
    ((90, 90, 0), (0, 0, 1), (0, -1, 0)),
    # y first, then z: +z -> (y 90) +x -> (z 90) +y. The other order would give +x.
    ((0, 90, 90), (0, 0, 1), (0, 1, 0)),
    # x, then z: +y -> (x 90) +z, unchanged by z. z first would give -x then (x 90) -x.
    ((90, 0, 90), (0, 1, 0), (0, 0, 1)),
])
def test_rotation_order_x_then_y_then_z(rotate, point, image):
    m = ObjectDesc(name="o", rotate_deg=rotate).transform()
    np.testing.assert_allclose(apply(m, point), image, atol=1e-12)


def test_rotate_90_90_0_is_the_hand_computed_matrix():
    m = ObjectDesc(name="o", rotate_deg=(90, 90, 0)).transform()
    # columns: images of +x, +y, +z worked out by hand (see above)
    np.testing.assert_allclose(m[:3, :3], [[0, 1, 0], [0, 0, -1], [-1, 0, 0]], atol=1e-12)


@pytest.mark.parametrize("rotate", [(10, 20, 30), (-45, 120, 75), (170, -80, 5)])
def test_transform_is_translate_rz_ry_rx_scale(rotate):
    scale, translate = (2.0, 0.5, 3.0), (1.0, -2.0, 4.0)
    m = ObjectDesc(name="o", rotate_deg=rotate, scale=scale, translate=translate).transform()
    expected = np.eye(4)
    expected[:3, :3] = rz(rotate[2]) @ ry(rotate[1]) @ rx(rotate[0]) @ np.diag(scale)
    expected[:3, 3] = translate
    np.testing.assert_allclose(m, expected, atol=1e-12)
    assert m.shape == (4, 4)
    np.testing.assert_array_equal(m[3], [0, 0, 0, 1])


def test_scale_before_rotation_translation_last():
    o = ObjectDesc(name="o", scale=(2.0, 1.0, 1.0), rotate_deg=(0, 0, 90), translate=(5.0, 0.0, 0.0))
    # (1,0,0) -> scaled (2,0,0) -> rotated (0,2,0) -> translated (5,2,0).
    # Rotating first would give (0,1,0) -> (0,1,0) -> (5,1,0); translating first (6,...).
    np.testing.assert_allclose(apply(o.transform(), (1, 0, 0)), (5, 2, 0), atol=1e-12)
    # Directions (w = 0) are not translated.
    np.testing.assert_allclose(o.transform() @ [0, 1, 0, 0], [-1, 0, 0, 0], atol=1e-12)


def test_parsed_object_transform():
    o = parse_scene(scene_with(object=[obj(translate=[1, 2, 3], rotate_deg=[0, 90, 0], scale=2)])).objects[0]
    np.testing.assert_allclose(apply(o.transform(), (1, 0, 0)), (1, 2, 1), atol=1e-12)


# ---------------------------------------------------------------- overrides


BASE = {"camera": {"fov_deg": 40, "position": [0, 0, 5], "look_at": [0, 0, 0]},
        "object": [{"name": "bunny", "mesh": "bunny.obj"}, {"name": "ball", "primitive": "sphere"}]}


def test_override_camera_fov():
    out = apply_overrides(BASE, ["camera.fov_deg=30"])
    assert out["camera"]["fov_deg"] == 30
    assert BASE["camera"]["fov_deg"] == 40  # the input is not modified
    assert parse_scene(out).camera.fov_deg == 30.0


def test_override_bare_word_is_a_string():
    out = apply_overrides(BASE, ["environment.map=constant"])
    assert out["environment"] == {"map": "constant"}
    assert parse_scene(out).environment.map == "constant"
    assert apply_overrides({}, ['environment.map="a b.exr"'])["environment"]["map"] == "a b.exr"


def test_override_object_by_name_and_index():
    out = apply_overrides(BASE, ["object.bunny.albedo=[1,0,0]", "object.1.translate=[1.5, 2, -3]",
                                 "object.0.scale=0.5"])
    assert out["object"][0]["albedo"] == [1, 0, 0]
    assert out["object"][0]["scale"] == 0.5
    assert out["object"][1]["translate"] == [1.5, 2, -3]
    s = parse_scene(out)
    assert s.objects[0].albedo == (1.0, 0.0, 0.0)
    assert s.objects[1].translate == (1.5, 2.0, -3.0)
    assert "albedo" not in BASE["object"][0]


def test_override_values_are_toml():
    out = apply_overrides({}, ["camera.resolution=[32,24]", "environment.intensity=2.5", "render.background=0",
                               "environment.params.value=[1, 2, 3]", "render.flag=true", "render.note=a=b"])
    assert out["camera"]["resolution"] == [32, 24]
    assert out["environment"]["intensity"] == 2.5
    assert out["render"]["background"] == 0 and out["render"]["flag"] is True
    assert out["render"]["note"] == "a=b"  # split at the first '='
    assert out["environment"]["params"]["value"] == [1, 2, 3]


def test_overrides_apply_in_order():
    assert apply_overrides({}, ["camera.fov_deg=30", "camera.fov_deg=50"])["camera"]["fov_deg"] == 50


def test_load_scene_applies_overrides(tmp_path):
    path = write_scene(tmp_path / "s.toml", FULL_TOML)
    s = load_scene(path, ["camera.fov_deg=30", "environment.map=constant", "object.bunny.albedo=[1,0,0]",
                          "object.1.translate=[0,1,0]", "camera.resolution=[32,24]"])
    assert s.camera.fov_deg == 30.0
    assert s.environment.map == "constant"
    assert s.objects[0].albedo == (1.0, 0.0, 0.0)
    assert s.objects[1].translate == (0.0, 1.0, 0.0)
    assert s.camera.resolution == (32, 24)


def test_overridden_values_are_checked(tmp_path):
    path = write_scene(tmp_path / "s.toml", FULL_TOML)
    with pytest.raises(InputError, match=r"\[camera\] fov_deg"):
        load_scene(path, ["camera.fov_deg=0"])
    with pytest.raises(InputError, match=r"\[camera\] has unknown key\(s\) fvo"):
        load_scene(path, ["camera.fvo=30"])
    with pytest.raises(InputError, match=r"\[object 'bunny'\] albedo\[0\]"):
        load_scene(path, ["object.bunny.albedo=[2,0,0]"])


@pytest.mark.parametrize("item, words", [
    ("camera.fov_deg", "not key=value"),
    ("fov_deg=30", "table.key"),
    ("camera.a.b.c=1", "table.key"),
    ("object.bunny=1", "object.NAME_OR_INDEX.key"),
    ("object.bunny.albedo.r=1", "object.NAME_OR_INDEX.key"),
    ("object.teapot.albedo=[1,0,0]", "teapot"),
    ("object.7.albedo=[1,0,0]", "'7'"),
])
def test_bad_override_forms(item, words):
    with pytest.raises(InputError) as info:
        apply_overrides(BASE, [item])
    assert words in str(info.value)


# ---------------------------------------------------------------- hostile files: errors, not tracebacks


@pytest.mark.parametrize("content, words", [
    (b"\xff\xfe[camera]\n", "is not UTF-8 text"),
    (b"[camera]\nfov_deg = 4\xe9\n", "is not UTF-8 text"),
    (("a = " + "[" * 3000 + "]" * 3000 + "\n").encode(), "nests arrays or tables too deeply"),
    (("[camera]\nfov_deg = " + "9" * 5000 + "\n").encode(), "cannot be read"),
], ids=["utf16-bom", "latin1", "deep-nesting", "5000-digits"])
def test_unreadable_scene_files_are_input_errors(tmp_path, content, words):
    path = tmp_path / "bad.toml"
    path.write_bytes(content)
    with pytest.raises(InputError, match=words) as err:
        load_scene(path)
    assert str(path) in str(err.value)


def test_huge_integers_are_out_of_range_not_overflow(tmp_path):
    path = write_scene(tmp_path / "big.toml", "[camera]\nfov_deg = " + "9" * 4000 + "\n")
    with pytest.raises(InputError, match=r"\[camera\] fov_deg must be a finite number") as err:
        load_scene(path)
    assert len(str(err.value)) < 200           # the value is shortened in the message
    path = write_scene(tmp_path / "face.toml", '[render]\nmethod = "reference"\nface_size = 4294967328\n')
    with pytest.raises(InputError, match=r"\[render\] face_size = 4294967328 is outside \[0, 256\]"):
        load_scene(path)


def test_set_values_that_cannot_be_read_are_input_errors():
    with pytest.raises(InputError, match="--set camera.fov_deg"):
        apply_overrides({}, ["camera.fov_deg=" + "[" * 3000 + "]" * 3000])
    with pytest.raises(InputError, match="--set camera.fov_deg"):
        apply_overrides({}, ["camera.fov_deg=" + "9" * 5000])


@pytest.mark.parametrize("kind", ["fifo", "folder", "device"])
def test_a_scene_path_that_is_not_a_file_is_refused_without_reading(tmp_path, kind):
    import os

    path = tmp_path / "scene.toml"
    if kind == "fifo":
        os.mkfifo(path)          # reading it would block for ever
    elif kind == "folder":
        path.mkdir()
    else:
        path = Path("/dev/zero")  # reading it would never end
    with pytest.raises(InputError, match=f"scene file {path} is (a folder|not a regular file)"):
        read_toml(path)
