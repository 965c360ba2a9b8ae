"""Eye-patch rendering: fidelity to normalization, labels, background fill, renderer agreement."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SINGLE_FACE_PHOTOS, face_photo

from facemesh.camera import camera_for_image
from facemesh.conventions import rotation_from_yaw_pitch
from facemesh.io import load_image_rgb
from facemesh.types import FaceMesh
from gazeaug.augment import face_asset, render_poses, sampled_placement, source_placement
from gazeaug.errors import GazeAugError
from gazeaug.normalize import NormalizationSettings, normalize_image
from gazeaug.pipeline import fit_face, mesh_for_fit
from gazeaug.render import create_renderer

TARGET = np.array([60.0, 90.0, -20.0])  # some point below and to the side of the camera, mm


@pytest.fixture(scope="module")
def fits(faces_dir, detector):
    """Fits of the single-face photos there are: all of them with ../shared, the astronaut without."""
    out = {}
    for name in SINGLE_FACE_PHOTOS:
        if not (faces_dir / name).is_file():
            continue
        image = load_image_rgb(faces_dir / name)
        h, w = image.shape[:2]
        out[name] = fit_face(image, camera_for_image(None, w, h, warn=False), detector, source=name)
    return out


@pytest.fixture(scope="module")
def assets(fits):
    return {name: face_asset(mesh_for_fit(fit)) for name, fit in fits.items()}


@pytest.fixture(scope="module")
def asset_of(assets, faces_dir):
    """The asset of photo ``name``, or without ../shared the astronaut's (the tests need a face, not this one)."""
    return lambda name: assets[face_photo(faces_dir, name, any_face=True).relative_to(faces_dir).as_posix()]


@pytest.mark.parametrize("name", SINGLE_FACE_PHOTOS)
def test_render_at_the_original_pose_matches_normalization(fits, assets, faces_dir, name):
    face_photo(faces_dir, name)  # each photo of ../shared; the astronaut without it
    fit, asset = fits[name], assets[name]
    ref = normalize_image(fit.image, fit.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, gaze_target_mm=TARGET)
    scene = create_renderer("raycast").scene(asset.render_mesh)
    out = render_poses(scene, asset, [source_placement(asset)], gaze_target_mm=TARGET)[0]
    for side in ("left", "right"):
        a, b = ref.eye(side), out.eye(side)
        assert np.abs(a.image.astype(float) - b.image).mean() <= 1.5
        assert np.degrees(np.abs(a.gaze - b.gaze)).max() <= 0.01
        assert np.degrees(np.abs(a.head_pose - b.head_pose)).max() <= 0.01
        assert b.coverage == 1.0


def test_the_face_patch_rendered_at_the_original_pose_matches_normalization(fits, assets, faces_dir):
    # the face camera (ETH-XGaze's 960 px at 600 mm, 224 x 224) through the same kernel: the whole
    # patch sees the head (face and background rings), and equals the photo's normalized face patch
    name = face_photo(faces_dir, "sergey.png").relative_to(faces_dir).as_posix()
    fit, asset = fits[name], assets[name]
    s = NormalizationSettings(face_patch_size_wh=(224, 224))
    ref = normalize_image(
        fit.image, fit.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, gaze_target_mm=TARGET, settings=s
    )
    scene = create_renderer("raycast").scene(asset.render_mesh)
    out = render_poses(scene, asset, [source_placement(asset)], gaze_target_mm=TARGET, settings=s)[0]
    assert out.face.image.shape == ref.face.image.shape == (224, 224, 3)
    assert np.abs(ref.face.image.astype(float) - out.face.image).mean() <= 1.5 and out.face.coverage == 1.0
    np.testing.assert_allclose(out.face.gaze, ref.face.gaze, atol=1e-6)
    # the eyes are what they are without a face patch
    plain = render_poses(scene, asset, [source_placement(asset)], gaze_target_mm=TARGET)[0]
    np.testing.assert_array_equal(plain.left.image, out.left.image)
    assert plain.face.image is None


def test_labels_at_a_new_pose_by_hand(asset_of):
    asset = asset_of("business-person.png")
    yaw, pitch = np.radians(12.0), np.radians(30.0)
    scene = create_renderer("raycast").scene(asset.render_mesh)
    out = render_poses(scene, asset, [sampled_placement(asset, yaw, pitch)], gaze_target_mm=[0.0, 0.0, 0.0])[0]
    # by hand: head frame -> new pose; target and eyes move with the head
    r_h, t_h = asset.mesh.pose.rotation, asset.mesh.pose.translation_mm
    d = np.linalg.norm(t_h)
    c, s = np.cos(yaw), np.sin(yaw)
    r_yaw = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    c, s = np.cos(pitch), np.sin(pitch)
    r_pitch = np.array([[1, 0, 0], [0, c, s], [0, -s, c]])
    r_new = r_pitch @ r_yaw
    t_new = np.array([0, 0, d])
    target = r_new @ (r_h.T @ (np.zeros(3) - t_h)) + t_new
    model = asset.model_vertices_mm
    for side, corners in (("left", (362, 263)), ("right", (33, 133))):
        e = r_new @ model[list(corners)].mean(axis=0) + t_new
        z = e / np.linalg.norm(e)
        y = np.cross(z, r_new[:, 0])
        y /= np.linalg.norm(y)
        x = np.cross(y, z)
        r = np.stack([x, y, z])
        g = r @ (target - e)
        g /= np.linalg.norm(g)
        gaze = np.array([np.arcsin(-g[1]), np.arctan2(-g[0], -g[2])])
        hz = (r @ r_new)[:, 2]
        head = np.array([np.arcsin(hz[1]), np.arctan2(hz[0], hz[2])])
        np.testing.assert_allclose(out.eye(side).gaze, gaze, atol=1e-9)
        np.testing.assert_allclose(out.eye(side).head_pose, head, atol=1e-9)
    # a camera 30 deg below: the head is seen pitched up (about +30 deg) in both eyes' frames
    assert 25 < np.degrees(out.left.head_pose[0]) < 35
    assert out.meta["yaw_pitch_deg"] == pytest.approx([12.0, 30.0])


@pytest.mark.parametrize("yaw, pitch", [(40, 0), (-40, 0), (0, 40), (0, -40), (28, 28), (-28, -28)])
def test_no_unfilled_pixels_up_to_40_degrees(asset_of, yaw, pitch):
    for name in ("astronaut.png", "business-person.png"):
        asset = asset_of(name)
        scene = create_renderer("raycast").scene(asset.render_mesh)
        out = render_poses(scene, asset, [sampled_placement(asset, np.radians(yaw), np.radians(pitch))])[0]
        # the mesh and its background rings cover every pixel (the inpainting is a last resort)
        assert out.left.coverage == 1.0 and out.right.coverage == 1.0, name


def test_renders_are_deterministic_and_batches_agree(asset_of):
    asset = asset_of("sergey.png")
    scene = create_renderer("raycast").scene(asset.render_mesh)
    places = [sampled_placement(asset, np.radians(y), np.radians(p)) for y, p in [(5, 25), (-10, 35), (0, 30)]]
    batch = render_poses(scene, asset, places)
    for place, b in zip(places, batch):
        one = render_poses(scene, asset, [place])[0]
        np.testing.assert_array_equal(one.left.image, b.left.image)
        np.testing.assert_array_equal(one.right.image, b.right.image)


def test_filament_agrees_with_ray_casting(asset_of):
    asset = asset_of("business-person.png")
    try:
        fil = create_renderer("filament").scene(asset.render_mesh)
    except (GazeAugError, ImportError) as exc:
        pytest.skip(f"Filament cannot start here: {exc}")
    ray = create_renderer("raycast").scene(asset.render_mesh)
    places = [source_placement(asset)] + [
        sampled_placement(asset, np.radians(y), np.radians(p)) for y, p in [(0, 30), (15, 20), (-20, 35), (10, -15)]
    ]
    a = render_poses(ray, asset, places)
    b = render_poses(fil, asset, places, renderer_name="filament")
    mads = [
        np.abs(x.eye(s).image.astype(float) - y.eye(s).image).mean() for x, y in zip(a, b) for s in ("left", "right")
    ]
    assert np.mean(mads) <= 3.0, mads


def test_bad_inputs(assets):
    asset = assets["astronaut.png"]
    scene = create_renderer("raycast").scene(asset.render_mesh)
    place = sampled_placement(asset, 0.0, 0.5)
    with pytest.raises(GazeAugError, match="finite"):
        render_poses(scene, asset, [place], gaze_target_mm=[np.nan, 0, 0])
    with pytest.raises(GazeAugError, match="zero-length"):
        render_poses(scene, asset, [place], gaze_vector=[0, 0, 0])
    with pytest.raises(GazeAugError, match="finite"):
        sampled_placement(asset, np.nan, 0.0)
    with pytest.raises(GazeAugError, match="distance"):
        sampled_placement(asset, 0.0, 0.0, distance_mm=-5)
    with pytest.raises(GazeAugError, match="renderer"):
        create_renderer("povray")
    m = asset.mesh
    small = FaceMesh(
        vertices_mm=m.vertices_mm[:10],
        triangles=[[0, 1, 2]],
        uv=m.uv[:10],
        texture=m.texture,
        texture_origin_px=m.texture_origin_px,
        landmarks=m.landmarks,
        camera=m.camera,
        pose=m.pose,
        face_model_name="ten",
        vertex_placement="canonical",
        model_vertices_mm=m.model_vertices_mm[:10],
    )
    with pytest.raises(GazeAugError, match="has no key points .*give them with --keypoints"):
        face_asset(small)
    # a head placed behind the camera
    behind = sampled_placement(asset, 0.0, 0.0)
    behind = type(behind)(rotation=behind.rotation, translation_mm=-behind.translation_mm)
    with pytest.raises(GazeAugError, match="behind the camera"):
        render_poses(scene, asset, [behind])


def test_rotation_convention_used_by_placements():
    # the placement uses the paper's R(y, p) = R_pitch(p) R_yaw(y); check one product by hand
    r = rotation_from_yaw_pitch(np.radians(90), 0.0)
    np.testing.assert_allclose(r @ [0, 0, -1], [-1, 0, 0], atol=1e-12)  # a face turned 90 deg to its right


# --------------------------------------------------------------------------- caster -> fragments -> shaders


def _two_mesh_caster():
    from facemesh.render import RayCaster

    # mesh 0: one triangle in the plane z = 10; mesh 1: a 200 mm square (two triangles) in the plane z = 20
    tri0 = (np.array([[0.0, 0, 10], [10, 0, 10], [0, 10, 10]]), np.array([[0, 1, 2]]))
    quad = np.array([[-100.0, -100, 20], [100, -100, 20], [100, 100, 20], [-100, 100, 20]])
    return RayCaster([tri0, (quad, np.array([[0, 1, 2], [0, 2, 3]]))])


def test_caster_fragments_by_hand():
    caster = _two_mesh_caster()
    assert caster.num_meshes == 2
    rays = np.zeros((2, 2, 6), dtype=np.float32)
    # toward (2, 3, 10): mesh 0, where (2, 3) = b1 (10, 0) + b2 (0, 10): b = (0.2, 0.3); t = 10 for direction z = 1
    rays[0, 0, 3:] = [0.2, 0.3, 1.0]
    # toward (8, 6, 10): outside mesh 0 (8 + 6 > 10); at z = 20 it is (16, 12), below the quad's diagonal y = x,
    # so triangle 0 (-100, -100), (100, -100), (100, 100): x = -100 + 200 b1 + 200 b2, y = -100 + 200 b2
    # -> b2 = 0.56, b1 = 0.02; t = 20
    rays[0, 1, 3:] = [0.8, 0.6, 1.0]
    # from (0, 50, 0) along z: at z = 20 it is (0, 50), above the diagonal: triangle 1 (-100, -100),
    # (100, 100), (-100, 100): x = -100 + 200 b1, y = -100 + 200 b1 + 200 b2 -> b1 = 0.5, b2 = 0.25; t = 20
    rays[1, 0] = [0.0, 50.0, 0.0, 0.0, 0.0, 1.0]
    # sideways: nothing
    rays[1, 1, 3:] = [1.0, 0.0, 0.0]
    f = caster.trace(rays)
    assert f.shape == (2, 2)
    assert f.mesh_id.dtype == np.int32 and f.triangle_id.dtype == np.int32
    assert f.barycentrics.dtype == np.float32 and f.barycentrics.shape == (2, 2, 2) and f.distance.dtype == np.float32
    np.testing.assert_array_equal(f.mesh_id, [[0, 1], [1, -1]])
    np.testing.assert_array_equal(f.triangle_id, [[0, 0], [1, -1]])
    np.testing.assert_array_equal(f.hit, [[True, True], [True, False]])
    np.testing.assert_allclose(f.barycentrics, [[[0.2, 0.3], [0.02, 0.56]], [[0.5, 0.25], [0.0, 0.0]]], atol=1e-5)
    np.testing.assert_allclose(f.distance[f.hit], [10.0, 20.0, 20.0], rtol=1e-5)
    assert np.isinf(f.distance[1, 1])
    np.testing.assert_allclose(f.points(rays, f.of_mesh(1)), [[16.0, 12.0, 20.0], [0.0, 50.0, 20.0]], atol=1e-4)


def test_caster_refuses_bad_meshes_and_rays():
    from facemesh.render import RayCaster
    from facemesh.types import InputError

    caster = RayCaster()
    with pytest.raises(InputError, match="no mesh"):
        caster.trace(np.zeros((1, 6)))
    with pytest.raises(InputError, match="without triangles"):
        caster.add_mesh(np.zeros((3, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(InputError, match="NaN"):
        caster.add_mesh(np.full((3, 3), np.nan), [[0, 1, 2]])
    caster.add_mesh(np.eye(3), [[0, 1, 2]])
    with pytest.raises(InputError, match="6"):
        caster.trace(np.zeros((4, 3)))


def test_camera_rays_by_hand():
    from facemesh.render import camera_rays, pinhole_pixel_to_ray

    k = np.array([[100.0, 0.0, 1.0], [0.0, 100.0, 0.5], [0.0, 0.0, 1.0]])
    rays = camera_rays(pinhole_pixel_to_ray(k), [1.0, 2.0, 3.0], (3, 2))
    assert rays.shape == (2, 3, 6) and rays.dtype == np.float32
    # pixel (x 2, y 1): K^-1 (2, 1, 1) = ((2 - 1) / 100, (1 - 0.5) / 100, 1)
    np.testing.assert_allclose(rays[1, 2], [1.0, 2.0, 3.0, 0.01, 0.005, 1.0], rtol=1e-6)
    # 2 x 2 samples per pixel: pixel (0, 0)'s first sample at (-0.25, -0.25)
    sub = camera_rays(pinhole_pixel_to_ray(k), np.zeros(3), (3, 2), supersample=2)
    assert sub.shape == (4, 6, 6)
    np.testing.assert_allclose(sub[0, 0, 3:], [-0.0125, -0.0075, 1.0], rtol=1e-6)
    # a turned camera: rows of R are its axes in the scene; R = a half turn about y: x -> -x, z -> -z
    r = np.diag([-1.0, 1.0, -1.0])
    turned = camera_rays(pinhole_pixel_to_ray(k, r), np.zeros(3), (3, 2))
    np.testing.assert_allclose(turned[1, 2, 3:], [-0.01, 0.005, -1.0], rtol=1e-6)
    # P cameras at once
    both = camera_rays(np.stack([pinhole_pixel_to_ray(k)] * 2), [[0.0, 0, 0], [5, 0, 0]], (3, 2))
    assert both.shape == (2, 2, 3, 6)
    np.testing.assert_allclose(both[1, 1, 2], [5.0, 0.0, 0.0, 0.01, 0.005, 1.0], rtol=1e-6)


def test_texel_table_by_hand():
    from facemesh.render import TexelTable

    caster = _two_mesh_caster()
    rays = np.zeros((2, 6), dtype=np.float32)
    rays[0, 3:] = [0.2, 0.3, 1.0]  # mesh 0 at b = (0.2, 0.3)
    rays[1, 3:] = [0.8, 0.6, 1.0]  # mesh 1
    f = caster.trace(rays)
    # uv (0, 0), (1, 0), (0, 1) of a 4 x 2 texture: corners at pixels (-0.5, -0.5), (3.5, -0.5), (-0.5, 1.5);
    # at b = (0.2, 0.3): (-0.5 + 0.2 * 4, -0.5 + 0.3 * 2) = (0.3, 0.1)
    table = TexelTable([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], [[0, 1, 2]], (4, 2))
    px = table.texture_px(f, f.of_mesh(0))
    assert px.shape == (2, 2) and px.dtype == np.float32
    np.testing.assert_allclose(px, [[0.3, 0.1], [0.0, 0.0]], atol=1e-5)  # mesh 1's fragment is not this table's


def test_shade_composites_one_shader_per_mesh():
    from facemesh.render import shade

    caster = _two_mesh_caster()
    rays = np.zeros((3, 6), dtype=np.float32)
    rays[:, 3:] = [[0.2, 0.3, 1.0], [0.8, 0.6, 1.0], [1.0, 0.0, 0.0]]  # mesh 0, mesh 1, nothing
    f = caster.trace(rays)

    def const(rgb):
        def shader(fragments, rays_, mask):
            out = np.zeros(fragments.shape + (3,), dtype=np.float32)
            out[mask] = rgb
            return out

        return shader

    out = shade(f, rays, {0: const([255, 0, 0]), 1: const([0, 0, 255])}, background=(0, 128, 0))
    np.testing.assert_array_equal(out, [[255, 0, 0], [0, 0, 255], [0, 128, 0]])
    out = shade(f, rays, {1: const([0, 0, 255])}, background=(0, 128, 0))  # a mesh without a shader: background
    np.testing.assert_array_equal(out, [[0, 128, 0], [0, 0, 255], [0, 128, 0]])


def test_eyeball_shader_by_hand():
    from facemesh.render import Fragments
    from gazeaug.render import EyeballShader

    c = np.array([0.0, 0.0, 100.0])
    eye = EyeballShader(c, np.array([0.0, 0.0, -1.0]), 12.0, 6.0, 2.0, np.array([100.0, 80.0, 60.0]))
    # hits on the sphere at 0, 20 and 45 deg from the optical axis (toward the camera), seen along +z;
    # the iris spans asin(6 / 12) = 30 deg, the pupil asin(2 / 12) = 9.6 deg
    angles = np.radians([0.0, 20.0, 45.0])
    points = c + 12.0 * np.stack([np.sin(angles), np.zeros(3), -np.cos(angles)], axis=1)
    rays = np.zeros((3, 6), dtype=np.float32)
    rays[:, :3] = points - [0.0, 0.0, 1.0]  # one unit before the hit, direction +z: distance 1
    rays[:, 5] = 1.0
    f = Fragments(
        mesh_id=np.zeros(3, np.int32),
        triangle_id=np.zeros(3, np.int32),
        barycentrics=np.zeros((3, 2), np.float32),
        distance=np.ones(3, np.float32),
    )
    out = eye(f, rays, np.array([True, True, True]))
    pupil = [18.0, 16.0, 16.0]
    iris = np.array([100.0, 80.0, 60.0]) * (1.0 - 0.45 * (20.0 / 30.0) ** 4)  # darker toward the limbus
    sclera = np.array([232.0, 226.0, 220.0]) * (0.55 + 0.45 * np.cos(np.radians(45.0)))  # seen 45 deg off its normal
    np.testing.assert_allclose(out, [pupil, iris, sclera], atol=1e-3)
    np.testing.assert_array_equal(eye(f, rays, np.array([False, True, False]))[[0, 2]], 0.0)


def test_background_rings_face_the_source_camera(assets):
    rm = assets["astronaut.png"].render_mesh
    v, tri = rm.vertices_mm, rm.triangles
    n = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    facing = np.einsum("ij,ij->i", n, -v[tri[:, 0]])  # normal . (camera centre - corner)
    ring = tri.max(axis=1) >= rm.num_face_vertices
    assert ring.sum() > 100 and (facing[ring] > 0).all()


def test_ring_vertices_name_the_contour_vertex_they_grew_from(assets):
    """Each ring vertex lies on the ray from the contour's centre through its parent (head frame, x and y)."""
    rm = assets["astronaut.png"].render_mesh
    n = rm.num_face_vertices
    parent = rm.ring_parent
    assert len(parent) == len(rm.vertices_mm) - n and parent.max() < n
    mesh = assets["astronaut.png"].mesh
    r, t = mesh.pose.rotation, mesh.pose.translation_mm
    head = (rm.vertices_mm - t) @ r
    outer = np.unique(parent)
    centre = head[outer, :2].mean(axis=0)
    a = head[n:, :2] - centre
    b = head[parent, :2] - centre
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    np.testing.assert_allclose(cross / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)), 0.0, atol=1e-9)
    assert ((a * b).sum(axis=1) > 0).all()  # the same side of the centre, farther out


# --------------------------------------------------------------------------- texture margin (docs/face_model.md)

#: The poses of the margin tests: heads turned 40 deg, where the background rings show most.
TURNED = [(y, p) for y in (-40, 40) for p in (-20, 0, 30)]


def _grey(sample, side):
    import cv2

    return cv2.cvtColor(sample.eye(side).image, cv2.COLOR_RGB2GRAY).astype(float)


def _renders(mesh, turned=TURNED):
    asset = face_asset(mesh)
    places = [sampled_placement(asset, np.radians(y), np.radians(p)) for y, p in turned]
    return asset, places, render_poses(create_renderer("raycast").scene(asset.render_mesh), asset, places)


def _glb(mesh, path):
    from facemesh.gltf import load_glb, save_glb

    save_glb(mesh, path)
    return load_glb(path)


@pytest.mark.parametrize("name", ["astronaut.png", "pexels/image01.jpg"])
def test_a_glb_with_the_default_margin_renders_like_the_photo(fits, faces_dir, tmp_path, name):
    """``gazeaug render face.glb`` (``facemesh build``'s default margin) = the render of the whole, uncropped photo.

    The reference is independent of any default: the same fit textured with the whole photo (a margin past
    its edges). image01 at yaw 40, pitch -20 is where the former direct-path margin, 0.4, was 50 grey
    levels off; the astronaut is where 0.15 was 177 off.
    """
    from facemesh.build import mesh_for_fit as facemesh_mesh_for_fit
    from facemesh.mesh import BuildSettings
    from gazeaug.augment import texture_shortfall

    face_photo(faces_dir, name)
    fit = fits[name]
    _, _, whole = _renders(facemesh_mesh_for_fit(fit, BuildSettings(texture_margin=2.0)))
    built = facemesh_mesh_for_fit(fit)  # what `facemesh build` writes
    asset, places, from_glb = _renders(_glb(built, tmp_path / "face.glb"))
    _, _, direct = _renders(mesh_for_fit(fit))  # what `gazeaug render photo` builds in memory
    for (y, p), a, b, ref in zip(TURNED, from_glb, direct, whole):
        for side in ("left", "right"):
            for got in (a, b):
                d = np.abs(_grey(got, side) - _grey(ref, side))
                assert d.max() <= 4 and d.mean() <= 0.05, (name, y, p, side, d.max(), d.mean())
    np.testing.assert_array_equal(texture_shortfall(asset, places), 0.0)  # so no warning


def test_texture_shortfall_flags_the_renders_a_tight_crop_changes(fits, faces_dir, tmp_path):
    """Patches the check leaves unflagged match the whole photo's render; those a tight crop spoils are flagged."""
    from facemesh.build import mesh_for_fit as facemesh_mesh_for_fit
    from facemesh.mesh import BuildSettings
    from gazeaug.augment import texture_shortfall

    name = face_photo(faces_dir, "business-person.png", any_face=True).relative_to(faces_dir).as_posix()
    fit = fits[name]
    _, _, whole = _renders(facemesh_mesh_for_fit(fit, BuildSettings(texture_margin=2.0)))
    spoiled = 0
    for margin in (0.15, 0.4):
        asset, places, got = _renders(
            _glb(facemesh_mesh_for_fit(fit, BuildSettings(texture_margin=margin)), tmp_path / "f.glb")
        )
        short = texture_shortfall(asset, places)
        assert short.shape == (len(TURNED), 2)
        for k, (a, ref) in enumerate(zip(got, whole)):
            for j, side in enumerate(("left", "right")):
                d = np.abs(_grey(a, side) - _grey(ref, side)).max()
                if short[k, j] == 0:
                    assert d <= 4, (margin, TURNED[k], side, d)
                spoiled += d > 20
    assert spoiled >= 2  # the tight crop costs some of these renders (not vacuous): all of them flagged


def test_gazeaug_render_warns_when_a_glb_crop_is_too_tight(fits, faces_dir, tmp_path, capsys):
    from facemesh.build import mesh_for_fit as facemesh_mesh_for_fit
    from facemesh.gltf import save_glb
    from facemesh.mesh import BuildSettings
    from gazeaug.cli import main

    fit = fits["astronaut.png"]
    tight, default = tmp_path / "tight.glb", tmp_path / "default.glb"
    save_glb(facemesh_mesh_for_fit(fit, BuildSettings(texture_margin=0.15)), tight)
    save_glb(facemesh_mesh_for_fit(fit), default)
    for glb, warned in ((tight, True), (default, False)):
        assert main(["render", str(glb), "--yaw", "40", "--pitch", "0", "-o", str(tmp_path / f"{glb.stem}.npz")]) == 0
        err = capsys.readouterr().err
        assert ("texture crop is too tight" in err) == warned, err
        assert ("--texture-margin" in err) == warned
    # the pose decides: the same tight crop suffices for the photo's own, frontal view
    assert main(["render", str(tight), "--yaw", "0", "--pitch", "0", "-o", str(tmp_path / "front.npz")]) == 0
    assert "texture crop is too tight" not in capsys.readouterr().err
