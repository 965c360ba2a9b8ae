"""From landmarks to a textured mesh: vertex placements, texture, and a render of the original view."""

import dataclasses
import json

import numpy as np
import pytest
from conftest import face_photo

from facemesh import BuildSettings, build_face_mesh, builtin_face_model, camera_for_image, load_camera, load_image_rgb
from facemesh.conventions import uv_to_pixels
from facemesh.face_models.triangulation import edge_use_counts
from facemesh.landmarks import select_face
from facemesh.pose import project_points
from facemesh.render import RaycastScene
from facemesh.types import FaceModel, InputError


@pytest.fixture(scope="module")
def mpii(mpii_sample, detector):
    ann = json.loads((mpii_sample / "annotation.json").read_text())
    img = load_image_rgb(mpii_sample / ann["image"])
    cam = load_camera(mpii_sample / "cameraCalib.xml", image_size=tuple(ann["image_size_wh"]))
    face = select_face(detector.detect(img))
    return img, cam, face


def test_backprojected_vertices_project_onto_their_landmarks_with_distortion(mpii):
    img, cam, face = mpii
    assert cam.has_distortion
    mesh = build_face_mesh(img, face, builtin_face_model(), cam)
    px = project_points(mesh.vertices_mm, cam)
    np.testing.assert_allclose(px, face.points_px[:468], atol=1e-3)
    # ... at the depth the posed model gives each vertex
    posed = mesh.pose.head_to_camera(builtin_face_model().vertices_mm)
    np.testing.assert_allclose(mesh.vertices_mm[:, 2], posed[:, 2], atol=1e-9)


def test_canonical_vertices_are_the_posed_model(mpii):
    img, cam, face = mpii
    model = builtin_face_model()
    mesh = build_face_mesh(img, face, model, cam, BuildSettings(vertex_placement="canonical"))
    np.testing.assert_allclose(mesh.vertices_mm, model.vertices_mm @ mesh.pose.rotation.T + mesh.pose.translation_mm)


def test_landmarks3d_vertices_follow_mediapipe_depth(mpii):
    img, cam, face = mpii
    mesh = build_face_mesh(img, face, builtin_face_model(), cam, BuildSettings(vertex_placement="landmarks3d"))
    np.testing.assert_allclose(project_points(mesh.vertices_mm, cam), face.points_px[:468], atol=1e-3)
    # depth differences are MediaPipe's z (pixels) times mm-per-pixel at the face
    z = face.points_3d[:468, 2]
    dz = mesh.vertices_mm[:, 2] - mesh.vertices_mm[:, 2].mean()
    scale = mesh.vertices_mm[:, 2].mean() / cam.focal_px[0]
    np.testing.assert_allclose(dz, (z - z.mean()) * scale, atol=1e-6)
    # the nose tip (1) is nearer the camera than the eye corners
    assert mesh.vertices_mm[1, 2] < mesh.vertices_mm[[33, 263], 2].min()


def test_landmarks3d_needs_3d_landmarks(mpii):
    img, cam, face = mpii
    flat = type(face)(points_px=face.points_px, model_name="user")
    with pytest.raises(InputError, match="landmarks3d"):
        build_face_mesh(img, flat, builtin_face_model(), cam, BuildSettings(vertex_placement="landmarks3d"))


def test_uv_points_at_the_landmark_pixels_of_the_texture(mpii):
    img, cam, face = mpii
    mesh = build_face_mesh(img, face, builtin_face_model(), cam)
    th, tw = mesh.texture.shape[:2]
    back = uv_to_pixels(mesh.uv, (tw, th)) + mesh.texture_origin_px
    np.testing.assert_allclose(back, face.points_px[:468], atol=1e-9)
    x0, y0 = mesh.texture_origin_px
    np.testing.assert_array_equal(mesh.texture, img[y0 : y0 + th, x0 : x0 + tw])
    assert tw < img.shape[1] and th < img.shape[0]  # a crop, not the whole image


@pytest.mark.parametrize("name", ["astronaut.png", "sergey.png"])
def test_render_of_the_original_view_reproduces_the_photo(faces_dir, detector, name):
    # Without distortion, ray casting the mesh from its own camera must give
    # back the photo wherever the face covers a pixel (up to bilinear sampling).
    img = load_image_rgb(face_photo(faces_dir, name))  # the astronaut runs without ../shared
    h, w = img.shape[:2]
    cam = camera_for_image(None, w, h, warn=False)
    face = select_face(detector.detect(img))
    mesh = build_face_mesh(img, face, builtin_face_model(), cam)
    res = RaycastScene.from_mesh(mesh).render(cam.matrix, (w, h))
    covered = res.coverage == 1.0
    assert covered.sum() > 1000
    diff = np.abs(res.image.astype(float) - img.astype(float))[covered]
    assert diff.mean() < 1.0, diff.mean()


def test_ball_pivoting_fallback_without_triangles(mpii):
    img, cam, face = mpii
    no_tri = FaceModel(name="points only", vertices_mm=builtin_face_model().vertices_mm)
    mesh = build_face_mesh(img, face, no_tri, cam)
    assert mesh.reconstruction["method"] == "bpa+fill"  # the default completion
    assert len(mesh.reconstruction["radii_mm"]) >= 1
    assert mesh.reconstruction["filled"]["left_open"] == 0
    counts = edge_use_counts(mesh.triangles)
    assert max(counts.values()) <= 2
    assert len(np.unique(mesh.triangles)) == 468
    # one boundary cycle: the face contour, no hole inside it (a disc: V - E + F = 1)
    assert 468 - len(counts) + mesh.num_triangles == 1
    # Poisson appends its own vertices after the 468 landmark vertices, textured where they project
    poisson = build_face_mesh(img, face, no_tri, cam, BuildSettings(reconstruction="poisson"))
    extra = poisson.reconstruction["appended_vertices"]
    assert extra["first_index"] == 468 and poisson.num_vertices == 468 + extra["count"]
    assert np.allclose(poisson.vertices_mm[:468], mesh.vertices_mm) and poisson.uv.shape == (poisson.num_vertices, 2)
    # a model of 6 points: too few for a surface; auto takes the planar fallback
    six_idx = [33, 133, 362, 263, 61, 291]
    six = FaceModel(name="six", vertices_mm=builtin_face_model().vertices_mm[six_idx])
    few = build_face_mesh(img, dataclasses.replace(face, points_px=face.points_px[six_idx], points_3d=None), six, cam)
    assert few.reconstruction["method"] == "delaunay" and few.num_triangles >= 4
    with pytest.raises(InputError, match="too few"):
        build_face_mesh(
            img,
            dataclasses.replace(face, points_px=face.points_px[six_idx], points_3d=None),
            six,
            cam,
            BuildSettings(reconstruction="bpa"),
        )
    assert BuildSettings(reconstruction="ball_pivoting").reconstruction == "bpa"  # the former name


def test_mismatched_inputs(mpii):
    img, cam, face = mpii
    with pytest.raises(InputError, match="camera is for"):
        build_face_mesh(img[:100], face, builtin_face_model(), cam)
    with pytest.raises(InputError, match="vertex placement"):
        BuildSettings(vertex_placement="magic")
