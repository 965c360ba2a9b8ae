"""Simulated identities: the shape space, the identity draw, lighting, glasses, realistic eyeballs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from facemesh.geometry import vertex_normals
from facemesh.render import Fragments
from gazeaug.render.shaders import EyeballShader, FlatShader, Light, LitShader
from gazeaug.simulate import Glasses, SimSettings, SubjectDraw, draw_subject


def _fragments(n, triangle_id=0, bary=(0.0, 0.0)):
    return Fragments(
        mesh_id=np.zeros(n, np.int32),
        triangle_id=np.full(n, triangle_id, np.int32),
        barycentrics=np.tile(np.asarray(bary, np.float32), (n, 1)),
        distance=np.ones(n, np.float32),
    )


# --------------------------------------------------------------------------- the shape space


def test_shape_space_is_an_orthonormal_basis_around_the_builtin_model():
    from facemesh.face_models import builtin_face_model
    from facemesh.face_models.shape_space import shape_space

    sp = shape_space()
    np.testing.assert_allclose(sp.mean_mm, builtin_face_model("mediapipe").vertices_mm, atol=1e-9)
    flat = sp.components.reshape(sp.num_components, -1)
    np.testing.assert_allclose(flat @ flat.T, np.eye(sp.num_components), atol=1e-5)
    assert (np.diff(sp.std_mm) <= 0).all() and sp.std_mm[-1] > 0  # sorted by spread
    # one standard deviation along component k moves the shape by std_k (mm, over all 1404 numbers)
    for k in (0, sp.num_components - 1):
        c = np.zeros(sp.num_components)
        c[k] = 1.0
        assert np.linalg.norm(sp.offset_mm(c)) == pytest.approx(sp.std_mm[k], rel=1e-5)
    # per point, the spread of faces is millimetres, not centimetres: plausible variety
    rms = float(np.sqrt((sp.std_mm**2).sum() / 468))
    assert 1.0 < rms < 8.0
    with pytest.raises(ValueError, match="expected shape"):
        sp.offset_mm(np.zeros(3))


def test_the_shape_space_leaves_out_pose_and_size():
    """Residuals after similarity alignment: no component is a rotation, a shift or a scaling of the mean."""
    from facemesh.face_models.shape_space import shape_space

    sp = shape_space()
    m = sp.mean_mm - sp.mean_mm.mean(axis=0)
    moves = [m / np.linalg.norm(m)]  # scaling
    for axis in np.eye(3):
        shift = np.tile(axis, (len(m), 1))
        moves.append(shift / np.linalg.norm(shift))
        rot = np.cross(axis, m)  # an infinitesimal rotation about the centroid
        moves.append(rot / np.linalg.norm(rot))
    for comp in sp.components:
        for mv in moves:
            assert abs(float((comp * mv).sum())) < 0.2


# --------------------------------------------------------------------------- the identity draw


def test_identity_draws_stay_in_their_ranges_and_repeat_with_the_seed():
    s = SimSettings()
    draws = [draw_subject(s, np.random.default_rng([0, i])) for i in range(200)]
    assert draw_subject(s, np.random.default_rng([0, 5])) == draws[5]
    for d in draws:
        assert s.eyeball_radius_range_mm[0] <= d.eyeball_radius_mm <= s.eyeball_radius_range_mm[1]
        assert s.iris_radius_range_mm[0] <= d.iris_radius_mm <= s.iris_radius_range_mm[1]
        assert s.pupil_radius_range_mm[0] <= d.pupil_radius_mm <= s.pupil_radius_range_mm[1]
        assert s.hole_scale_range[0] <= d.hole_scale <= s.hole_scale_range[1]
        assert len(d.shape_coefficients) == 12
        json.dumps(d.as_dict())  # recorded in simulation.jsonl
    glasses = sum(d.glasses is not None for d in draws) / len(draws)
    own_iris = sum(d.iris_rgb is None for d in draws) / len(draws)
    assert 0.12 < glasses < 0.38 and 0.18 < own_iris < 0.42  # shares 0.25 and 0.3
    fixed = draw_subject(SimSettings(vary_identity=False, kappa_deg=0.0), np.random.default_rng(0))
    assert fixed == SubjectDraw(
        eyeball_radius_mm=12.0, iris_radius_mm=6.0, pupil_radius_mm=2.0, hole_scale=0.92, kappa_deg=(0.0, 0.0)
    )


# --------------------------------------------------------------------------- shaders


def test_light_factor_by_hand():
    light = Light(np.array([0.0, 0.0, -1.0]), ambient=0.4, reference=0.9)
    n = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -math.sin(0.5), -math.cos(0.5)]])
    want = np.array([1.0, 0.4, 0.4, 0.4 + 0.6 * math.cos(0.5)]) / (0.4 + 0.6 * 0.9)
    np.testing.assert_allclose(light.factor(n), want, atol=1e-12)


def test_lit_shader_interpolates_vertex_normals():
    tri = np.array([[0, 1, 2]])
    normals = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    light = Light(np.array([0.0, 0.0, -1.0]), ambient=0.0, reference=1.0)
    base = FlatShader((100.0, 100.0, 100.0))
    lit = LitShader(base, normals, tri, light)
    rays = np.zeros((2, 6), np.float32)
    # at the first corner the normal faces the light: full colour; halfway to the second corner the
    # interpolated normal (0.5, 0, -0.5) normalized makes 45 deg with the light: cos 45 deg
    f = Fragments(
        mesh_id=np.zeros(2, np.int32),
        triangle_id=np.zeros(2, np.int32),
        barycentrics=np.array([[0.0, 0.0], [0.5, 0.0]], np.float32),
        distance=np.ones(2, np.float32),
    )
    out = lit(f, rays, np.array([True, True]))
    np.testing.assert_allclose(out[:, 0], [100.0, 100.0 * math.cos(math.pi / 4)], atol=1e-3)


def test_vertex_normals_of_a_flat_square():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    t = np.array([[0, 1, 2], [0, 2, 3]])
    np.testing.assert_allclose(vertex_normals(v, t), np.tile([0.0, 0.0, 1.0], (4, 1)))


def _eye_hits(angles_deg, shader):
    c = shader.centre_mm
    a = np.radians(angles_deg)
    points = c + shader.radius_mm * np.stack([np.sin(a), np.zeros(len(a)), -np.cos(a)], axis=1)
    rays = np.zeros((len(a), 6), dtype=np.float32)
    rays[:, :3] = points - [0.0, 0.0, 1.0]
    rays[:, 5] = 1.0
    return shader(_fragments(len(a)), rays, np.ones(len(a), bool))


def test_soft_limbus_blends_half_way_at_the_iris_edge():
    c = np.array([0.0, 0.0, 100.0])
    iris_rgb = np.array([100.0, 80.0, 60.0])
    hard = EyeballShader(c, np.array([0.0, 0.0, -1.0]), 12.0, 6.0, 2.0, iris_rgb)
    soft = EyeballShader(c, np.array([0.0, 0.0, -1.0]), 12.0, 6.0, 2.0, iris_rgb, limbus_soft_deg=4.0)
    edge = 30.0  # asin(6 / 12)
    h = _eye_hits([edge - 0.01, edge + 0.01, edge - 3.0, edge + 3.0], hard)
    s = _eye_hits([edge, edge - 3.0, edge + 3.0], soft)
    np.testing.assert_allclose(s[0], 0.5 * (h[0] + h[1]), atol=0.5)  # the smoothstep's midpoint
    np.testing.assert_allclose(s[1:], h[2:], atol=1e-3)  # outside the band: unchanged


def test_corneal_highlight_peaks_at_the_mirror_direction():
    c = np.array([0.0, 0.0, 100.0])
    light = Light(np.array([0.0, 0.0, -1.0]), ambient=1.0, specular=150.0)
    eye = EyeballShader(c, np.array([0.0, 0.0, -1.0]), 12.0, 6.0, 2.0, np.array([100.0, 80.0, 60.0]), light=light)
    plain = EyeballShader(c, np.array([0.0, 0.0, -1.0]), 12.0, 6.0, 2.0, np.array([100.0, 80.0, 60.0]))
    # viewer and light both along -z: the mirror point is the cornea's apex (0 deg)
    diff = _eye_hits([0.0, 8.0], eye) - _eye_hits([0.0, 8.0], plain)
    np.testing.assert_allclose(diff[0], 150.0, atol=1e-3)
    assert (diff[1] < 5.0).all()  # cos(8 deg)^400 ~ 0.02


# --------------------------------------------------------------------------- subjects


@pytest.fixture(scope="module")
def photo(detector):
    from facemesh.build import sample_image
    from gazeaug.simulate import PhotoFace

    return PhotoFace.from_image(sample_image(), detector, "astronaut")


def _interocular(subj):
    return float(np.linalg.norm(subj.eye_centre["left"] - subj.eye_centre["right"]))


def test_head_scale_scales_the_eyes_distance(photo):
    from gazeaug.simulate import SimSubject

    s = SimSettings()
    base = SimSubject(photo, "a", s, SubjectDraw())
    big = SimSubject(photo, "b", s, SubjectDraw(head_scale=1.1))
    assert _interocular(big) == pytest.approx(1.1 * _interocular(base), rel=1e-9)
    # a shape draw moves the landmarks by the shape space's offset (before the eye openings shrink)
    from facemesh.face_models.shape_space import shape_space

    c = np.zeros(12)
    c[0] = 2.0
    moved = SimSubject(photo, "c", s, SubjectDraw(shape_coefficients=tuple(c)))
    nose = 4  # a landmark on no eye contour
    np.testing.assert_allclose(moved.head[nose] - base.head[nose], shape_space().offset_mm(c)[nose], atol=1e-9)


def test_glasses_show_in_front_of_the_eyes(photo):
    from gazeaug.simulate import SimSubject

    s = SimSettings(relight=False, brightness=(1.0, 1.0), blur_sigma_px=(0.0, 0.0), noise_sigma=(0.0, 0.0))
    g = Glasses(rim_mm=4.0, rgb=(200.0, 20.0, 20.0))
    subj = SimSubject(photo, "g", s, SubjectDraw(glasses=g))
    k = np.array([[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]])
    r, t = np.eye(3), np.array([0.0, 0.0, 450.0])
    frame = subj.render(r, t, np.array([0.0, 0.0, 0.0]), k, (640, 480), np.random.default_rng(0))
    # the middle of the outer side of each rim: centre + (half width + rim / 2) along x, in front of the eye
    for side, sign in (("left", 1.0), ("right", -1.0)):
        c = subj.eye_centre[side]
        p = np.array([c[0] + sign * (g.half_width_mm + g.rim_mm / 2), c[1] + g.drop_mm, c[2] - g.distance_mm]) + t
        u, v = (k @ p)[:2] / p[2]
        px = frame.image[int(round(v)), int(round(u))].astype(float)
        np.testing.assert_allclose(px, g.rgb, atol=30)  # JPEG


def test_simulate_records_identities(tmp_path):
    from gazeaug.datasets import open_dataset
    from gazeaug.sampling import BUILTIN_RIGS
    from gazeaug.simulate import simulate

    out = tmp_path / "sim"
    summary = simulate([None], BUILTIN_RIGS["screen"], out, per_face=4, identities_per_face=2, progress=False)
    assert summary["subjects"] == 2
    subjects = [s.subject for s in open_dataset(out)]
    assert subjects == ["sim00i00", "sim00i01", "sim00i00", "sim00i01"]
    rows = [json.loads(line) for line in (out / "simulation.jsonl").read_text().splitlines()]
    assert rows[0]["subject_draw"] == rows[2]["subject_draw"] != rows[1]["subject_draw"]
    assert set(rows[0]["light"]) == {"direction", "ambient", "specular"}
    with pytest.raises(Exception, match="identities per face"):
        simulate([None], BUILTIN_RIGS["screen"], tmp_path / "x", per_face=2, identities_per_face=3, progress=False)


def test_simulate_takes_face_sources_and_records_the_person(tmp_path):
    from facemesh.build import sample_image
    from gazeaug.faces import FaceSource
    from gazeaug.sampling import BUILTIN_RIGS
    from gazeaug.simulate import simulate

    src = FaceSource(name="clip@t=1.00s", image=sample_image(), origin="clip.mp4@t=1.00s", person="clip")
    out = tmp_path / "sim"
    simulate([src], BUILTIN_RIGS["screen"], out, per_face=1, progress=False)
    row = json.loads((out / "simulation.jsonl").read_text().splitlines()[0])
    assert row["person"] == "clip" and row["source_face"] == "clip.mp4@t=1.00s"


# --------------------------------------------------------------------------- what is read from the photo


def _ellipse(centre, axes, n=16):
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.stack([centre[0] + axes[0] * np.cos(a), centre[1] + axes[1] * np.sin(a)], axis=1)


def test_skin_around_the_eyes_is_read_beyond_the_dark_lid_margin():
    """Bands about each eye, in the contour's own scale: opening 230, lid margin 30, skin 150, beyond 2x 60.

    The reading is the skin's band (1.3-2.0 x the contour), where SKIN_RING_SCALES lie; the contour
    itself lies on the margin.
    """
    from gazeaug.simulate import SKIN_RING_SCALES, skin_around_eyes

    w, h = 500, 360
    centres, axes = ((130.0, 180.0), (330.0, 180.0)), (40.0, 14.0)
    ys, xs = np.mgrid[0:h, 0:w]
    # each pixel's scale relative to the nearer eye's contour ellipse (1 on the contour)
    k = np.min([np.hypot((xs - cx) / axes[0], (ys - cy) / axes[1]) for cx, cy in centres], axis=0)
    grey = np.select([k < 1.0, k < 1.3, k < 2.0], [230, 30, 150], 60).astype(np.uint8)
    tex = np.repeat(grey[..., None], 3, axis=2)
    contours = {"left": list(range(16)), "right": list(range(16, 32))}
    px = np.concatenate([_ellipse(centres[0], axes), _ellipse(centres[1], axes)])
    uv = (px + 0.5) / [w, h]  # the inverse of uv_to_pixels
    assert 1.3 < min(SKIN_RING_SCALES) and max(SKIN_RING_SCALES) < 2.0  # the skin band, as set above
    assert skin_around_eyes(tex, uv, contours) == pytest.approx(150.0)
    # a texture of another size: its pixels are found through the same uv
    big = np.repeat(np.repeat(tex, 2, axis=0), 2, axis=1)
    assert skin_around_eyes(big, uv, contours) == pytest.approx(150.0)


def test_iris_colour_leaves_out_what_the_lids_cover():
    """An iris half under the upper lid: only its pixels inside the eye contour count."""
    import cv2

    from gazeaug.simulate import _iris_colour, eye_contours

    iris_rgb, lid_rgb = (40, 90, 160), (200, 150, 120)
    img = np.zeros((200, 200, 3), np.uint8)
    img[:] = lid_rgb
    loop = eye_contours()["right"]
    pts = np.zeros((478, 2))
    pts[loop] = _ellipse((100, 114), (60, 12), len(loop))  # the opening: y from 102 to 126
    inside = np.zeros((200, 200), np.uint8)
    cv2.fillPoly(inside, [np.round(pts[loop]).astype(np.int32)], 1)
    img[inside > 0] = (235, 230, 225)  # sclera
    iris = np.zeros((200, 200), np.uint8)
    cv2.circle(iris, (100, 100), 20, 1, -1)
    img[(iris > 0) & (inside > 0)] = iris_rgb  # the iris shows only inside the opening
    pts[468] = (100, 100)
    pts[469:473] = [(120, 100), (100, 80), (80, 100), (100, 120)]
    # most of the ring (45-90 % of the radius) lies above the opening, under the lid
    ys, xs = np.mgrid[0:200, 0:200]
    d = np.hypot(xs - 100, ys - 100)
    ring = (d > 9) & (d < 18)
    assert (ring & (inside > 0)).sum() < 0.5 * ring.sum()
    np.testing.assert_allclose(_iris_colour(img, pts, "right"), iris_rgb)


def test_iris_colour_falls_back_to_the_ring_then_to_a_default():
    """Under a closed lid the whole ring is read; an iris off the image gives the default brown."""
    from gazeaug.simulate import _iris_colour, eye_contours

    img = np.full((200, 200, 3), (200, 150, 120), np.uint8)  # all lid
    loop = eye_contours()["right"]
    pts = np.zeros((478, 2))
    pts[loop] = _ellipse((100, 170), (60, 8), len(loop))  # the opening far below the iris
    pts[468] = (100, 100)
    pts[469:473] = [(120, 100), (100, 80), (80, 100), (100, 120)]
    np.testing.assert_allclose(_iris_colour(img, pts, "right"), (200, 150, 120))
    pts[468:473] += (0, -400)  # the iris above the image
    np.testing.assert_allclose(_iris_colour(img, pts, "right"), (90, 70, 50))


def test_a_larger_eyeball_sits_deeper_so_that_its_front_stays(photo):
    from gazeaug.simulate import SimSubject, eyeball_depth_mm

    # by hand: 10.5 mm behind the contour for 12 mm; 13 mm sits 1 mm deeper, 11.5 mm 0.5 mm shallower
    assert eyeball_depth_mm(10.5, 12.0) == 10.5
    assert eyeball_depth_mm(10.5, 13.0) == 11.5
    assert eyeball_depth_mm(10.5, 11.5) == 10.0
    s = SimSettings(relight=False)
    for radius in (11.5, 12.0, 13.0):
        subj = SimSubject(photo, "e", s, SubjectDraw(eyeball_radius_mm=radius))
        for side, loop in subj.contours.items():
            contour_centre = subj.head[np.asarray(loop)].mean(axis=0)
            # the centre lies straight behind the contour's centre (head frame +z) ...
            np.testing.assert_allclose(subj.eye_centre[side][:2], contour_centre[:2], atol=1e-9)
            # ... with its front surface 1.5 mm behind the contour whatever the radius
            assert subj.eye_centre[side][2] - radius - contour_centre[2] == pytest.approx(-1.5, abs=1e-9)


# --------------------------------------------------------------------------- skin mixed between photos


def test_warp_texture_follows_each_triangles_affine_map():
    """Two triangles (a square) in both layouts; the source texture holds its own pixel coordinates.

    Target layout: the square [20, 60] x [10, 50] px of an 80 x 64 texture; source layout: the
    square [100, 180] x [40, 200] px of a 256 x 256 texture, so target (x, y) must read source
    (100 + 2 (x - 20), 40 + 4 (y - 10)): derived by hand from the two squares' corners.
    """
    from facemesh.conventions import pixels_to_uv
    from gazeaug.simulate import warp_texture

    tri = np.array([[0, 1, 2], [0, 2, 3]])
    src_px = np.array([[100.0, 40.0], [180.0, 40.0], [180.0, 200.0], [100.0, 200.0]])
    dst_px = np.array([[20.0, 10.0], [60.0, 10.0], [60.0, 50.0], [20.0, 50.0]])
    src_uv = pixels_to_uv(src_px, (0.0, 0.0), (256, 256))
    dst_uv = pixels_to_uv(dst_px, (0.0, 0.0), (80, 64))
    ys, xs = np.mgrid[0:256, 0:256].astype(np.float32)
    tex = np.stack([xs, ys, np.full_like(xs, 7.0)], axis=2)
    out, covered = warp_texture(tex, src_uv, dst_uv, tri, (80, 64))
    assert out.shape == (64, 80, 3) and out.dtype == np.float32 and covered.shape == (64, 80)
    yy, xx = np.mgrid[0:64, 0:80]
    inside = (xx >= 21) & (xx <= 59) & (yy >= 11) & (yy <= 49)
    assert covered[inside].all() and not covered[(xx < 19) | (xx > 61) | (yy < 9) | (yy > 51)].any()
    np.testing.assert_allclose(out[..., 0][inside], (100 + 2 * (xx - 20))[inside], atol=1e-3)
    np.testing.assert_allclose(out[..., 1][inside], (40 + 4 * (yy - 10))[inside], atol=1e-3)
    assert (out[..., 2][covered] == 7.0).all() and (out[~covered] == 0).all()


def test_other_photo_index_spreads_over_other_people():
    from gazeaug.errors import GazeAugError
    from gazeaug.simulate import other_photo_index

    picks = np.linspace(0.0, 0.999, 400)
    for n in (2, 3, 9):
        persons = [f"p{k}" for k in range(n)]
        for i in range(n):
            got = [other_photo_index(i, persons, p) for p in picks]
            assert i not in got and set(got) == set(range(n)) - {i}
            counts = np.bincount(got, minlength=n)
            assert counts.max() - counts[counts > 0].min() <= 2  # equal shares of [0, 1)
    # the frames of one video are one person: never mixed with each other
    persons = ["clip", "clip", "clip", "anna"]
    assert {other_photo_index(i, persons, p) for i in range(3) for p in picks} == {3}
    assert {other_photo_index(3, persons, p) for p in picks} == {0, 1, 2}
    with pytest.raises(GazeAugError, match="another person"):
        other_photo_index(0, ["clip", "clip"], 0.5)
    with pytest.raises(GazeAugError, match="pick"):
        other_photo_index(0, persons, 1.0)
    with pytest.raises(GazeAugError, match="face index"):
        other_photo_index(4, persons, 0.5)


def test_texture_mix_draws_last_and_leaves_other_draws_alone():
    plain = [draw_subject(SimSettings(), np.random.default_rng([3, i])) for i in range(60)]
    mixed = [draw_subject(SimSettings(texture_mix_share=0.5), np.random.default_rng([3, i])) for i in range(60)]
    from dataclasses import replace

    assert all(p.texture_mix_pick is None and p.texture_mix_weight == 0.0 for p in plain)
    assert [replace(m, texture_mix_pick=None, texture_mix_weight=0.0) for m in mixed] == plain
    chosen = [m for m in mixed if m.texture_mix_pick is not None]
    assert 15 <= len(chosen) <= 45
    assert all(0.0 <= m.texture_mix_pick < 1.0 and 0.25 <= m.texture_mix_weight <= 0.6 for m in chosen)
    from gazeaug.errors import GazeAugError

    for bad in ({"texture_mix_share": 1.5}, {"texture_mix_weight": (0.5,)}, {"texture_mix_weight": (0.6, 0.2)}):
        with pytest.raises(GazeAugError, match="texture mix"):
            SimSettings(**bad)
    assert SimSettings(texture_mix_share=np.float32(0.5)).texture_mix_share == 0.5


def test_simulate_mixes_skin_between_faces(tmp_path, faces_dir):
    """Every subject mixed: each names the other face; the images differ from the unmixed run's, the labels not."""
    from conftest import face_photo

    from gazeaug.errors import GazeAugError
    from gazeaug.sampling import BUILTIN_RIGS
    from gazeaug.simulate import simulate

    second = face_photo(faces_dir, "sergey.png", any_face=True)
    if second.stem == "astronaut":  # without ../shared: the built-in photo again, its red and blue swapped
        from facemesh.io import load_image_rgb, save_image_rgb

        save_image_rgb(tmp_path / "other.png", load_image_rgb(second)[..., ::-1].copy())
        second = tmp_path / "other.png"
    faces = [None, second]
    plain, mixed = tmp_path / "plain", tmp_path / "mixed"
    simulate(faces, BUILTIN_RIGS["screen"], plain, per_face=1, progress=False)
    simulate(
        faces, BUILTIN_RIGS["screen"], mixed, per_face=1, progress=False, settings=SimSettings(texture_mix_share=1.0)
    )
    rows = [json.loads(line) for line in (mixed / "simulation.jsonl").read_text().splitlines()]
    base = [json.loads(line) for line in (plain / "simulation.jsonl").read_text().splitlines()]
    assert [r["texture_mixed_with"] for r in rows] == [base[1]["source_face"], base[0]["source_face"]]
    assert all(r["texture_mixed_with"] is None for r in base)
    assert (mixed / "labels.csv").read_text() == (plain / "labels.csv").read_text()
    from facemesh.io import load_image_rgb

    a = load_image_rgb(plain / "sim00" / "00000.jpg").astype(float)
    b = load_image_rgb(mixed / "sim00" / "00000.jpg").astype(float)
    changed = np.abs(a - b).max(axis=2) > 20  # the face's skin (11-17k px of 307k, measured); nothing else drawn moved
    assert changed.sum() > 2000 and not changed[:, :100].any() and not changed[:, -100:].any()
    with pytest.raises(GazeAugError, match="two people"):
        simulate(
            [None],
            BUILTIN_RIGS["screen"],
            tmp_path / "one",
            per_face=1,
            progress=False,
            settings=SimSettings(texture_mix_share=0.5),
        )
    from facemesh.build import sample_image
    from gazeaug.faces import FaceSource
    from gazeaug.sequence import SequenceSettings, simulate_sequence

    frames = [
        FaceSource(name=f"clip@t={t}s", image=sample_image(), origin=f"clip.mp4@t={t}s", person="clip") for t in (1, 2)
    ]
    with pytest.raises(GazeAugError, match="show 1"):  # two frames of one video: one person
        simulate(
            frames,
            BUILTIN_RIGS["screen"],
            tmp_path / "clip",
            per_face=1,
            progress=False,
            settings=SimSettings(texture_mix_share=0.5),
        )
    with pytest.raises(GazeAugError, match="a sequence simulates one"):
        simulate_sequence(
            None,
            BUILTIN_RIGS["wheelchair"],
            tmp_path / "seq",
            sequence=SequenceSettings(pattern="calibration"),
            settings=SimSettings(texture_mix_share=0.5),
        )
    assert not (tmp_path / "clip").exists() and not (tmp_path / "seq").exists()


def test_cli_simulate_sequence_refuses_texture_mix(tmp_path, capsys):
    from pathlib import Path

    from gazeaug.cli import main

    rig = Path(__file__).resolve().parents[1] / "data_samples" / "rigs" / "wheelchair_objects.yaml"
    out = tmp_path / "seq"
    assert main(["simulate", "--texture-mix", "0.5", "--sequence", "1", "--rig", str(rig), "-o", str(out)]) == 2
    assert "a sequence simulates one" in capsys.readouterr().err and not out.exists()
