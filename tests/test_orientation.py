"""The lat-long orientation convention, proved on a labelled map and on synthetic maps.

Convention (the same as Mitsuba 3; right-handed, y up): pixel (column i, row j)
of a W x H map looks along

    phi = 2 pi (i + 0.5) / W,  theta = pi (j + 0.5) / H,
    d = (sin phi sin theta, cos theta, -cos phi sin theta),

so the top row is +y, u = 0 is -z, u = 0.25 is +x, u = 0.5 is +z, u = 0.75 is -x.
An env map's rotation_deg turns it about +y: world direction d sees the map at
R_y(-angle) d, with R_y(a) = [[cos a, 0, sin a], [0, 1, 0], [-sin a, 0, cos a]].

What ``OrientationLatLong.exr`` shows (OpenEXR sample image, 1024 x 512, read
with read_envmap, saved as PNG and viewed): it is a cube map of six labelled
faces resampled to lat-long, on white. Every face carries the same light-blue
paragraph of text ("their method of divining by lots is exceedingly simple. From
a tree which bears fruit they cut a twig ...") and faint pink grid lines, and, in
black:

* a label just below its centre naming the face's axis: "+X", "-X", "+Y", "-Y",
  "+Z", "-Z" (pixel boxes of the four horizontal labels in LABELS below);
* an axis gizmo: two dark (black/dark red) lines about 25 degrees long leaving
  the exact centre of the face towards the two positive axes that are
  perpendicular to it, each ending in its letter. On the +X face a line goes up to
  "Y" and one goes towards +z to "Z"; on +Y the lines go to +x and +z.

Looked at from inside the sphere with a right-handed camera (right = forward x
up), every face reads correctly (no mirror writing) and its gizmo lines point
at the axes their letters name. In the lat-long image the four horizontal faces
sit side by side: the gizmo corners of +X, +Z, -X are at columns 256, 512, 768
(u = 0.25, 0.5, 0.75) and -Z at column 0 = 1024 (u = 0), all on the middle row
(256); +Y fills the top rows and -Y the bottom rows. So the file agrees with the
convention above, half-pixel centres included. There are no distinctive colours
per axis (all faces are white, light blue and black), so the tests read the
black marks: the gizmo lines and the label glyphs.

The tests render what penumbra returns for a direction (unshadowed method,
background = 1, camera at the origin looking along an axis; the G-buffer's
position plane gives each background pixel's view direction) and check the marks
there, and check the cube map (EnvMap.cube_radiance, faces +X -X +Y -Y +Z -Z)
with synthetic maps that do not depend on the file.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import penumbra
from penumbra.imageio import read_envmap

ORIENTATION = "envmaps/OrientationLatLong.exr"
FACES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")  # order of the cube faces
AXIS = {"+X": (1, 0, 0), "-X": (-1, 0, 0), "+Y": (0, 1, 0), "-Y": (0, -1, 0), "+Z": (0, 0, 1), "-Z": (0, 0, -1)}
# Camera up vector of each view, chosen so that the file's face reads upright.
UP = {"+X": (0, 1, 0), "-X": (0, 1, 0), "+Y": (0, 0, 1), "-Y": (0, 0, -1), "+Z": (0, 1, 0), "-Z": (0, 1, 0)}
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)

# Landmarks in the 1024 x 512 file, read off the image (dark connected
# components): the column of each horizontal face's gizmo corner (all on the
# boundary between rows 255 and 256), and for its label the left column of the
# sign glyph box (16 x 16 from row 274), the sign's centre column, and the left
# column of the letter glyph box (20 x 24 from row 267). Columns wrap at 1024.
CORNER = {"+X": 256, "+Z": 512, "-X": 768, "-Z": 1024}
SIGN_CENTRE = {"+X": 232.0, "+Z": 519.5, "-X": 775.5, "-Z": 999.0}
LETTER = {"+X": 238, "+Z": 526, "-X": 782, "-Z": 1005}
CORNER_ROW = 256

# Views are rendered with one pixel at the image centre spanning one file pixel
# (2 pi / 1024 radians), so glyphs keep the file's size: n * pi / 1024 = tan(fov / 2).
VIEW = 160
VIEW_FOV = 2.0 * math.degrees(math.atan(VIEW * math.pi / 1024))
CENTRE = VIEW // 2  # the view's centre lies between pixels CENTRE - 1 and CENTRE


def darkness(lum: np.ndarray) -> np.ndarray:
    """1 for black ink, 0 for white paper and the light-blue text (luminance >= 0.5)."""
    return np.clip((0.5 - lum) / 0.5, 0.0, 1.0)


def render_background(ctx, env, forward, up, fov_deg, n):
    """(unit view directions (n, n, 3), RGBA (n, n, 4)) of an empty scene seen from the origin."""
    scene = penumbra.Scene(ctx)
    scene.set_envmap(env)
    scene.set_camera(penumbra.Camera(position=(0, 0, 0), look_at=forward, up=up, fov_deg=fov_deg, resolution=(n, n)))
    scene.commit()
    gbuffer, image = penumbra.GBuffer(ctx, n, n), penumbra.Image(ctx, n, n)
    scene.render_gbuffer(gbuffer)
    penumbra.Renderer(ctx, "unshadowed", background=1).execute(scene, gbuffer, image)
    assert (gbuffer.read("instance") == penumbra.BACKGROUND).all()
    d = gbuffer.read("position")[..., :3].astype(np.float64)
    return d / np.linalg.norm(d, axis=-1, keepdims=True), image.read()


def ry(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


# ---------------------------------------------------------------- the labelled file


@pytest.fixture(scope="module")
def orientation_map(shared_data) -> np.ndarray:
    env = read_envmap(shared_data / ORIENTATION)
    assert env.shape == (512, 1024, 3)
    return env


@pytest.fixture(scope="module")
def views(ctx, orientation_map):
    """views(rotation_deg) -> {axis name: (directions, RGBA)} of the file, six renders per rotation."""
    cache: dict[float, dict] = {}

    def get(rotation_deg: float = 0.0):
        if rotation_deg not in cache:
            env = penumbra.EnvMap(ctx, orientation_map, face_size=256, irradiance_face_size=2,
                                  rotation_deg=rotation_deg)
            cache[rotation_deg] = {name: render_background(ctx, env, AXIS[name], UP[name], VIEW_FOV, VIEW)
                                   for name in FACES}
        return cache[rotation_deg]

    return get


def test_file_landmarks(orientation_map):
    """The marks this module relies on are where the docstring says (a check of the data, not of penumbra)."""
    dark = darkness(orientation_map @ LUMA) > 0.5
    cols = lambda c0, c1: np.arange(c0, c1) % 1024  # noqa: E731
    for name, c in CORNER.items():
        c %= 1024
        assert dark[200:254, c].all() or dark[200:254, c - 1].all(), name  # vertical gizmo line up to "Y"
        right = name in ("+X", "-Z")  # the horizontal line points to +z (on +X) or +x (on -Z): to the right
        span = cols(c + 2, c + 55) if right else cols(c - 55, c - 2)
        other = cols(c - 55, c - 2) if right else cols(c + 2, c + 55)
        assert dark[255, span].all() and not dark[255, other].any(), name
        letter = dark[267:291, cols(LETTER[name], LETTER[name] + 20)]
        assert letter.sum() > 40, name  # a letter is there
        sign_rows = dark[270:292, cols(int(SIGN_CENTRE[name]) - 2, int(SIGN_CENTRE[name]) + 2)].any(axis=1).sum()
        if name[0] == "+":
            assert sign_rows >= 11, name  # "+" has a vertical stroke 12 rows tall
        else:
            assert 1 <= sign_rows <= 3, name  # "-" is 2 rows tall (1 or 2 above the threshold)


def sign_height(view_dark: np.ndarray, label: str) -> int:
    """Rows of dark ink around the sign glyph of `label`'s face, placed relative to the view's centre."""
    c = CENTRE + SIGN_CENTRE[label] - CORNER[label]
    if c < 0:  # -Z's corner is column 1024 = 0
        c += 1024
    c = int(round(c))
    rows = view_dark[CENTRE + 270 - CORNER_ROW:CENTRE + 292 - CORNER_ROW, c - 3:c + 3]
    return int((rows > 0.5).any(axis=1).sum())


def letter_scores(view_dark: np.ndarray, file_dark: np.ndarray, label: str) -> dict[str, float]:
    """Best normalised correlation, within 4 pixels of where `label`'s letter should be, with each
    of the file's four label letters (X from +X and -X, Z from +Z and -Z)."""
    r0 = CENTRE + 267 - CORNER_ROW
    c0 = CENTRE + LETTER[label] - CORNER[label]
    out = {}
    for name, col in LETTER.items():
        t = file_dark[267:291, np.arange(col, col + 20) % 1024]
        best = -1.0
        for dr in range(-4, 5):
            for dc in range(-4, 5):
                w = view_dark[r0 + dr:r0 + dr + t.shape[0], c0 + dc:c0 + dc + t.shape[1]]
                best = max(best, float(np.corrcoef(w.ravel(), t.ravel())[0, 1]))
        out[name] = best
    return out


# (rotation_deg, view axis, the face of the file that must be seen there):
# world d sees the map at R_y(-angle) d; R_y(-90) takes -Z to +X, +X to +Z, +Z to -X, -X to -Z.
LABEL_CASES = [(0, a, a) for a in ("+X", "+Z", "-X", "-Z")] + \
              [(90, "-Z", "+X"), (90, "+X", "+Z"), (90, "+Z", "-X"), (90, "-X", "-Z")]


@pytest.mark.parametrize("rotation, view, label", LABEL_CASES)
def test_views_show_the_file_label_of_their_axis(views, orientation_map, rotation, view, label):
    """Looking along an axis, penumbra shows that axis's label from the file, upright and unmirrored."""
    assert np.allclose(ry(-rotation) @ AXIS[view], AXIS[label], atol=1e-12)  # the case table is right
    _, rgba = views(rotation)[view]
    view_dark = darkness(rgba[..., :3] @ LUMA)
    file_dark = darkness(orientation_map @ LUMA)

    # The sign: "+" has a vertical stroke 12 rows tall, "-" is 2 rows tall.
    h = sign_height(view_dark, label)
    if label[0] == "+":
        assert h >= 9, f"expected a '+' at the {label} label, ink is {h} rows tall"
    else:
        assert 1 <= h <= 4, f"expected a '-' at the {label} label, ink is {h} rows tall"

    # The letter: the file's X glyphs for ±X, Z glyphs for ±Z, by a clear margin.
    scores = letter_scores(view_dark, file_dark, label)
    same = [s for n, s in scores.items() if n[1] == label[1]]
    other = [s for n, s in scores.items() if n[1] != label[1]]
    assert min(same) > 0.65, scores
    assert min(same) > max(other) + 0.2, scores


@pytest.mark.parametrize("view", FACES)
def test_gizmo_lines_point_to_the_positive_axes(views, view):
    """From the centre of each face, dark lines run towards the two positive perpendicular axes only."""
    dirs, rgba = views(0.0)[view]
    lum = rgba[..., :3] @ LUMA
    forward, up = np.array(AXIS[view], float), np.array(UP[view], float)
    right = np.cross(forward, up)
    np.testing.assert_allclose(dirs[CENTRE, CENTRE], forward, atol=0.01)  # the view is centred on the axis
    for b in (up, -up, right, -right):
        dx, dy = int(b @ right), int(-(b @ up))  # pixel step towards world axis b
        hits = []
        for r in range(6, 51):  # 2 to 18 degrees from the centre
            x, y = CENTRE + r * dx, CENTRE + r * dy
            across = [(y, x + k) for k in (-1, 0)] if dx == 0 else [(y + k, x) for k in (-1, 0)]
            across += [(y, x - 2)] if dx == 0 else [(y - 2, x)]
            hits.append(min(lum[p] for p in across) < 0.5)
        fraction = float(np.mean(hits))
        if b.sum() > 0:  # towards +x, +y or +z
            assert fraction > 0.9, f"{view}: no gizmo line towards {b} ({fraction:.2f})"
        else:
            assert fraction < 0.3, f"{view}: ink towards {b} ({fraction:.2f})"


def _box_blur(x: np.ndarray, k: int = 2) -> np.ndarray:
    p = np.pad(x, k, mode="edge")
    c = np.pad(np.cumsum(np.cumsum(p, 0), 1), ((1, 0), (1, 0)))
    n = 2 * k + 1
    return (c[n:, n:] - c[:-n, n:] - c[n:, :-n] + c[:-n, :-n]) / (n * n)


@pytest.mark.parametrize("view", FACES)
def test_views_match_the_convention_and_no_flipped_variant(views, orientation_map, view):
    """The ink of each rendered view matches the file sampled with the convention, and clearly
    less well with any of the 15 other orientations (u offset by a quarter turn, u mirrored, v flipped)."""
    dirs, rgba = views(0.0)[view]
    file_lum = orientation_map @ LUMA
    h, w = file_lum.shape
    seen = _box_blur(darkness(rgba[..., :3] @ LUMA))

    def predicted(mirror, offset, flip):
        u = (mirror * np.arctan2(dirs[..., 0], -dirs[..., 2]) / (2 * np.pi) + offset) % 1.0
        v = np.arccos(np.clip(flip * dirs[..., 1], -1, 1)) / np.pi
        return _box_blur(darkness(file_lum[np.minimum((v * h).astype(int), h - 1),
                                           np.minimum((u * w).astype(int), w - 1)]))

    scores = {(m, o, f): float(np.corrcoef(seen.ravel(), predicted(m, o, f).ravel())[0, 1])
              for m in (1, -1) for o in (0.0, 0.25, 0.5, 0.75) for f in (1, -1)}
    right = scores.pop((1, 0.0, 1))
    assert right > 0.94, right
    runner_up = max(scores, key=scores.get)
    assert right > scores[runner_up] + 0.03, (right, runner_up, scores[runner_up])


# ---------------------------------------------------------------- synthetic maps


def convention_direction(i: float, j: float, w: int, h: int) -> np.ndarray:
    phi, theta = 2 * np.pi * (i + 0.5) / w, np.pi * (j + 0.5) / h
    return np.array([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)])


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)))))


def brightest_texel(ctx, env_map, **params):
    env = penumbra.EnvMap(ctx, env_map, face_size=32, irradiance_face_size=2, **params)
    radiance = env.cube_radiance().sum(axis=-1)
    dirs, _ = env.cube_directions()
    face, j, i = np.unravel_index(np.argmax(radiance), radiance.shape)
    return radiance, int(face), dirs[face, j, i].astype(np.float64)


W, H = 64, 32


@pytest.mark.parametrize("col, row, face", [
    (W // 4, H // 2, "+X"),      # u ~ 0.25
    (W // 2, H // 2, "+Z"),      # u ~ 0.5
    (3 * W // 4, H // 2, "-X"),  # u ~ 0.75
    (0, H // 2, "-Z"),           # u ~ 0
    (W - 1, H // 2, "-Z"),       # u ~ 1 wraps to -z
    (5, 0, "+Y"),                # the top row
    (40, H - 1, "-Y"),           # the bottom row
])
def test_bright_pixel_lands_on_the_predicted_face(ctx, col, row, face):
    env_map = np.zeros((H, W, 3), np.float32)
    env_map[row, col] = 100.0
    radiance, got, d = brightest_texel(ctx, env_map)
    assert FACES[got] == face
    assert d @ AXIS[face] > 0.95  # near the face's axis ...
    # ... at the pixel's direction: within a texel (2.8 degrees at face_size 32); the next pixel
    # of the 64 x 32 map is 3 (near the poles) to 5.6 degrees away
    assert angle_deg(d, convention_direction(col, row, W, H)) < 2.5
    others = [f for f in range(6) if f != got]
    assert radiance[others].max() < 1e-3 * radiance[got].max()  # nowhere else


@pytest.mark.parametrize("rotation, col, face", [
    (90, W // 4, "-Z"),    # +X content: R_y(90) (1,0,0) = (0,0,-1)
    (90, W // 2, "+X"),    # +Z content: R_y(90) (0,0,1) = (1,0,0)
    (-90, W // 4, "+Z"),   # +X content: R_y(-90) (1,0,0) = (0,0,1)
    (180, W // 4, "-X"),
    (360, W // 4, "+X"),
])
def test_rotation_moves_content_where_the_convention_predicts(ctx, rotation, col, face):
    env_map = np.zeros((H, W, 3), np.float32)
    env_map[H // 2, col] = 100.0
    _, got, d = brightest_texel(ctx, env_map, rotation_deg=rotation)
    assert FACES[got] == face
    # world d sees the map at R_y(-angle) d, so map direction m appears at R_y(angle) m
    expected = ry(rotation) @ convention_direction(col, H // 2, W, H)
    assert angle_deg(d, expected) < 2.5


# A colour per axis; the synthetic map paints each pixel with the colour of the
# axis nearest to its direction, so each cube face should come out in one colour.
AXIS_COLOUR = {"+X": (1, 0, 0), "-X": (0, 1, 1), "+Y": (0, 1, 0), "-Y": (1, 0, 1), "+Z": (0, 0, 1), "-Z": (1, 1, 0)}


@pytest.fixture(scope="module")
def axis_coloured_map() -> np.ndarray:
    w, h = 256, 128
    jj, ii = np.mgrid[0:h, 0:w]
    d = np.moveaxis(convention_direction(ii, jj, w, h), 0, -1)
    k = np.argmax(np.abs(d), axis=-1)
    sign = np.take_along_axis(d, k[..., None], axis=-1)[..., 0] > 0
    names = np.array([["-X", "+X"], ["-Y", "+Y"], ["-Z", "+Z"]])[k, sign.astype(int)]
    colours = np.array([AXIS_COLOUR[n] for n in names.ravel()], np.float32)
    return colours.reshape(h, w, 3)


def test_cube_faces_take_the_colour_of_their_axis(ctx, axis_coloured_map):
    env = penumbra.EnvMap(ctx, axis_coloured_map, face_size=16, irradiance_face_size=2)
    cube = env.cube_radiance()
    dirs, _ = env.cube_directions()
    for f, name in enumerate(FACES):
        mean_dir = dirs[f].reshape(-1, 3).mean(axis=0)
        np.testing.assert_allclose(mean_dir / np.linalg.norm(mean_dir), AXIS[name], atol=1e-5)  # face order
        texels = cube[f].reshape(-1, 3)
        exact = np.all(np.abs(texels - AXIS_COLOUR[name]) < 1e-4, axis=-1)
        assert exact.mean() > 0.75, (name, exact.mean())  # all but texels along the edges
        np.testing.assert_allclose(np.median(texels, axis=0), AXIS_COLOUR[name], atol=1e-4)  # dominant colour
        np.testing.assert_allclose(cube[f, 8, 8], AXIS_COLOUR[name], atol=1e-6)


@pytest.mark.parametrize("rotation", [0, 90])
def test_camera_looking_along_an_axis_sees_its_colour(ctx, axis_coloured_map, rotation):
    env = penumbra.EnvMap(ctx, axis_coloured_map, face_size=16, irradiance_face_size=2, rotation_deg=rotation)
    for name in FACES:
        d, rgba = render_background(ctx, env, AXIS[name], UP[name], 30.0, 8)
        np.testing.assert_allclose(d[3:5, 3:5], np.broadcast_to(AXIS[name], (2, 2, 3)), atol=0.15)
        assert (rgba[..., 3] == 0).all()  # background pixels carry alpha 0
        # the map seen along world d is the map's own direction R_y(-angle) d
        seen = ry(-rotation) @ AXIS[name]
        seen_name = next(n for n, a in AXIS.items() if np.allclose(a, seen, atol=1e-9))
        np.testing.assert_allclose(rgba[3:5, 3:5, :3], np.broadcast_to(AXIS_COLOUR[seen_name], (2, 2, 3)),
                                   atol=1e-5)
