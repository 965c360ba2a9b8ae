"""The shipped face model: close to MediaPipe's reference, clean triangulation, documented frame."""

import numpy as np
import pytest

from facemesh import builtin_face_model, load_face_model
from facemesh.face_models import EYE_CORNERS, export_obj, mirror_permutation
from facemesh.face_models.triangulation import boundary_loops, edge_use_counts
from facemesh.geometry import apply_similarity, nearest_rotation, similarity_transform


@pytest.fixture(scope="module")
def model():
    return builtin_face_model()


def _rms_after_similarity(a, b):
    s, r, t = similarity_transform(a, b)
    return float(np.sqrt(np.mean(np.sum((apply_similarity(a, s, r, t) - b) ** 2, axis=1))))


def test_similarity_transform_recovers_a_known_transform():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(20, 3))
    th = 0.3
    r = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    b = 2.5 * a @ r.T + [1.0, -2.0, 3.0]
    s, r2, t = similarity_transform(a, b)
    assert s == pytest.approx(2.5)
    np.testing.assert_allclose(r2, r, atol=1e-12)
    np.testing.assert_allclose(t, [1.0, -2.0, 3.0], atol=1e-12)


def test_nearest_rotation_by_hand():
    th = np.radians(30.0)
    r = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    # a rotation scaled keeps its rotation; one stored in float32 comes back orthonormal to float64
    np.testing.assert_allclose(nearest_rotation(3.0 * r), r, atol=1e-12)
    r32 = nearest_rotation(r.astype(np.float32))
    assert np.abs(r32 @ r32.T - np.eye(3)).max() < 1e-12 and np.abs(r32 - r).max() < 1e-6
    # diag(2, 1, -0.5) = U S V^T with U = diag(1, 1, -1), V = I: U V^T is a reflection, so the
    # smallest singular direction flips and the nearest proper rotation is the identity
    np.testing.assert_allclose(nearest_rotation(np.diag([2.0, 1.0, -0.5])), np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="finite"):
        nearest_rotation(np.full((3, 3), np.nan))


def test_builtin_model_shape(model):
    assert model.vertices_mm.shape == (468, 3)
    assert model.triangles is not None and model.triangles.shape == (898, 3)


def test_within_7mm_rms_of_mediapipe_reference(model, reference_model_path):
    ref = load_face_model(reference_model_path)
    rms = _rms_after_similarity(model.vertices_mm, ref.vertices_mm)
    assert rms <= 7.0, f"{rms:.2f} mm RMS"


def test_reference_loads_alike_from_obj_and_pbtxt(reference_model_path):
    obj = load_face_model(reference_model_path)
    pbtxt = load_face_model(reference_model_path.parent / "geometry_pipeline_metadata_landmarks.pbtxt")
    np.testing.assert_allclose(obj.vertices_mm, pbtxt.vertices_mm, atol=1e-9)
    assert pbtxt.triangles is not None and len(pbtxt.triangles) == 898


def test_head_frame_axes(model):
    v = model.vertices_mm
    right_eye = v[list(EYE_CORNERS["right"])].mean(axis=0)
    left_eye = v[list(EYE_CORNERS["left"])].mean(axis=0)
    np.testing.assert_allclose((right_eye + left_eye) / 2, 0, atol=1e-9)  # origin between the eyes
    assert right_eye[0] < 0 < left_eye[0]  # x toward the subject's left
    assert v[152, 1] > 80  # chin (152) far down +y
    assert v[1, 2] < -20  # nose tip (1) toward the viewer, -z
    eye_distance = np.linalg.norm(left_eye - right_eye)
    assert 55 < eye_distance < 70  # metric scale: adult eye-centre distance


def test_mirror_permutation_matches_the_reference_symmetry(model, reference_model_path):
    # The reference is exactly left-right symmetric; our derived partner
    # permutation must map it onto its own mirror image.
    ref = load_face_model(reference_model_path).vertices_mm
    perm = mirror_permutation()
    np.testing.assert_allclose(ref[perm] * [-1, 1, 1], ref, atol=1e-4)
    np.testing.assert_allclose(model.vertices_mm[perm] * [-1, 1, 1], model.vertices_mm, atol=1e-6)


def test_triangulation_is_manifold_oriented_and_closes_eyes_and_mouth(model):
    tri = model.triangles
    counts = edge_use_counts(tri)
    assert max(counts.values()) == 2
    directed = [(a, b) for t in tri.tolist() for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))]
    assert len(directed) == len(set(directed)), "some directed edge appears twice: inconsistent winding"
    loops = boundary_loops(tri)
    assert [len(loop) for loop in loops] == [36], "only the outer face contour may stay open"
    # Every vertex used; disk topology: V - E + F = 1
    assert len(np.unique(tri)) == 468
    assert 468 - len(counts) + len(tri) == 1
    # Right-hand normals point out of the face (toward -z in the head frame).
    v = model.vertices_mm
    n = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    assert (n[:, 2] < 0).mean() > 0.95


def test_eye_contours_are_interior(model):
    # MediaPipe's own eye-contour edge lists: each edge must be shared by two
    # triangles, i.e. the eye opening is covered.
    fm = pytest.importorskip("mediapipe").solutions.face_mesh
    counts = edge_use_counts(model.triangles)
    for edges in (fm.FACEMESH_LEFT_EYE, fm.FACEMESH_RIGHT_EYE):
        for a, b in edges:
            assert counts[(min(a, b), max(a, b))] == 2, f"eye edge {(a, b)} is open"


def test_export_obj_round_trip(model, tmp_path):
    path = tmp_path / "model.obj"
    path.write_text(export_obj(model))
    back = load_face_model(path)
    np.testing.assert_allclose(back.vertices_mm, model.vertices_mm, atol=1e-6)
    np.testing.assert_array_equal(back.triangles, model.triangles)


def test_mpii_six_point_model_loads_3xN(mpii_sample):
    m = load_face_model(mpii_sample / "faceModelGeneric.txt")
    assert m.vertices_mm.shape == (6, 3)
    assert m.vertices_mm[0, 0] < 0 < m.vertices_mm[3, 0]  # eye corners left to right in x


# --------------------------------------------------------------------------- determinism of the derivation
#
# The shipped model is left-right symmetric to ~1e-13 mm, so the mouth opening
# (a mirror-symmetric loop) offers pairs of mirror-image ears of equal quality
# to the ear clipper. Which one is cut first was a floating-point accident
# (another machine's BLAS or summation order): 4 of 898 triangles differed.
# Ties are now broken by rule; these tests perturb the inputs by far more than
# the rounding noise and demand the very same triangles.


def _canonical_rows(triangles):
    """Each triangle rotated to start at its smallest index (winding kept), as a sorted list."""
    out = []
    for t in np.asarray(triangles).tolist():
        k = t.index(min(t))
        out.append(tuple(t[k:] + t[:k]))
    return sorted(out)


# A unit square and a regular hexagon, counter-clockwise (y up). Every ear of
# the square is a right isosceles triangle (smallest angle 45 deg): a four-way
# exact tie. Hexagon (side s): an ear (i-1, i, i+1) has angles 120/30/30 deg;
# after a cut the new ears at the cut's ends are right triangles with legs s
# and s*sqrt(3) (30/60/90 deg): again smallest angle 30 deg everywhere. The
# rule (among ears within EAR_QUALITY_TIE_RAD of the best, cut the one whose
# apex has the largest vertex index) then cuts, by hand:
#   square:  apex 3 -> (2, 3, 0); left (0, 1, 2)
#   hexagon: apex 5 -> (4, 5, 0); apex 4 -> (3, 4, 0); apex 3 -> (2, 3, 0); left (0, 1, 2)
SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
HEXAGON = np.array([[np.cos(a), np.sin(a)] for a in np.deg2rad(np.arange(0, 360, 60))])
EXPECTED_EARS = {
    "square": (SQUARE, [(2, 3, 0), (0, 1, 2)]),
    "hexagon": (HEXAGON, [(4, 5, 0), (3, 4, 0), (2, 3, 0), (0, 1, 2)]),
}


@pytest.mark.parametrize("shape", sorted(EXPECTED_EARS))
def test_ear_clip_breaks_exact_ties_by_the_documented_rule(shape):
    from facemesh.face_models.triangulation import ear_clip

    points, expected = EXPECTED_EARS[shape]
    n = len(points)
    rng = np.random.default_rng(7)
    for trial in range(50):
        noisy = points + rng.choice([-1e-12, 0.0, 1e-12], size=points.shape)
        start = trial % n  # the rule must not depend on where the loop starts either
        loop = [(start + k) % n for k in range(n)]
        assert _canonical_rows(ear_clip(loop, noisy)) == _canonical_rows(expected), f"trial {trial}"


def test_ear_clip_rejects_a_polygon_it_cannot_clip():
    from facemesh.face_models.triangulation import ear_clip

    # A "polygon" whose points all lie on one line has no ear.
    with pytest.raises(ValueError, match="not simple"):
        ear_clip([0, 1, 2, 3], np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]))


def test_triangulation_of_the_shipped_model_is_stable_under_rounding_noise(model):
    # The shipped vertices are as symmetric as the derivation's (mirror pairs
    # agree to ~1e-13 mm), so mirror-image ears of the mouth tie here too.
    # (The derivation triangulates before its final levelling, in another
    # frame, so this mouth closure need not be the shipped one; what matters
    # is that it does not move.) Moving every coordinate by +-1e-12 mm, ten
    # times the noise between machines, must not change a single triangle.
    fm = pytest.importorskip("mediapipe").solutions.face_mesh
    from facemesh.face_models.triangulation import clean_triangulation_from_edges

    v = model.vertices_mm
    assert np.abs(v[mirror_permutation()] * [-1, 1, 1] - v).max() < 1e-12  # the premise: exact-looking symmetry
    reference = clean_triangulation_from_edges(fm.FACEMESH_TESSELATION, v)
    rng = np.random.default_rng(2024)
    for trial in range(20):
        noisy = v + rng.choice([-1e-12, 1e-12], size=v.shape)
        tri = clean_triangulation_from_edges(fm.FACEMESH_TESSELATION, noisy)
        np.testing.assert_array_equal(tri, reference, err_msg=f"trial {trial}")


@pytest.fixture(scope="module")
def derivation_inputs():
    pytest.importorskip("mediapipe")
    from facemesh.face_models import derive_mediapipe

    return derive_mediapipe.derivation_inputs()


def _assert_reproduces(arrays, model):
    # Vertices: floating-point sums in another order may move them by ~1e-13 mm.
    np.testing.assert_allclose(arrays["vertices_mm"], model.vertices_mm, rtol=0, atol=1e-9)
    # Combinatorial results: decided by exact rules, identical everywhere.
    np.testing.assert_array_equal(arrays["triangles"], model.triangles)
    np.testing.assert_array_equal(arrays["mirror"], mirror_permutation())


def test_derivation_reproduces_the_shipped_model(model, derivation_inputs):
    from facemesh.face_models.derive_mediapipe import derive_from_landmarks

    arrays = derive_from_landmarks(*derivation_inputs)
    _assert_reproduces(arrays, model)
    assert len(arrays["sources"]) == 100  # 2 portraits + 98 of the 100 LFW crops


def test_derivation_is_deterministic_under_rounding_noise(model, derivation_inputs):
    # Another machine's rounding, simulated: MediaPipe's landmarks moved by a
    # relative +-1e-12 (about 1e-10 px) give the same model.
    from facemesh.face_models.derive_mediapipe import derive_from_landmarks

    names, shapes, edges = derivation_inputs
    rng = np.random.default_rng(11)
    for _ in range(3):
        noisy = [s * (1.0 + rng.choice([-1e-12, 1e-12], size=s.shape)) for s in shapes]
        _assert_reproduces(derive_from_landmarks(names, noisy, edges), model)


def test_key_points_belong_to_the_face_model(tmp_path):
    """Set by each loader (or the user), never guessed from the point count."""
    import facemesh
    from facemesh.face_models import KEYPOINTS, load_face_model, parse_keypoints, resolve_face_model
    from facemesh.types import FaceKeypoints, FaceModel, InputError

    builtin = facemesh.builtin_face_model()
    assert builtin.keypoints == FaceKeypoints((33, 133), (362, 263), (61, 291))
    # a plain matrix says nothing: no key points, whatever its point count
    six = np.array([[-45, 0, 2], [-21, 0, -2], [21, 0, -2], [45, 0, 2], [-26, 69, 0], [26, 69, 0]], float)
    np.savetxt(tmp_path / "six.txt", six.T)
    assert load_face_model(tmp_path / "six.txt").keypoints is None
    m = load_face_model(tmp_path / "six.txt", keypoints=KEYPOINTS["mpii6"])
    assert m.keypoints == KEYPOINTS["mpii6"]
    # with key points the head frame's origin is the midpoint of the four eye corners: (0, 0, 0) here
    np.testing.assert_allclose(m.vertices_mm, six, atol=1e-12)
    shifted = load_face_model(_saved(tmp_path / "s.npy", six + [5, -3, 7]), keypoints=KEYPOINTS["mpii6"])
    np.testing.assert_allclose(shifted.vertices_mm, six, atol=1e-12)
    # the exported OBJ records them, and reads back with them
    (tmp_path / "m.obj").write_text(facemesh.face_models.export_obj(m))
    assert load_face_model(tmp_path / "m.obj").keypoints == KEYPOINTS["mpii6"]
    assert resolve_face_model("mediapipe", KEYPOINTS["dlib68"]).keypoints == KEYPOINTS["dlib68"]
    # the command lines' spelling
    assert parse_keypoints("mpii6") == KEYPOINTS["mpii6"]
    assert parse_keypoints("1,2,3,4") == FaceKeypoints((1, 2), (3, 4), None)
    assert parse_keypoints(" 0,1,2,3,4,5 ") == FaceKeypoints((0, 1), (2, 3), (4, 5))
    for bad in ("eyes", "1,2,3", "1,2,3,4,5", "-1,2,3,4", "a,b,c,d"):
        with pytest.raises(InputError, match="key points"):
            parse_keypoints(bad)
    with pytest.raises(InputError, match=r"do not fit a 6-point model"):
        FaceModel("six", six, keypoints=KEYPOINTS["mediapipe"])


def _saved(path, array):
    np.save(path, array)
    return path


def test_a_mesh_records_its_key_points(tmp_path):
    import facemesh
    from facemesh.face_models import KEYPOINTS

    mesh = facemesh.build_mesh(
        facemesh.sample_image(),
        facemesh.default_camera(512, 512),
        facemesh.landmarks.MediaPipeFaceMesh(),
        face_model=facemesh.builtin_face_model().with_keypoints(KEYPOINTS["dlib68"]),  # any, to see it travel
    )
    assert mesh.model_keypoints == KEYPOINTS["dlib68"]
    facemesh.save(mesh, tmp_path / "f.glb")
    assert facemesh.load(tmp_path / "f.glb").model_keypoints == KEYPOINTS["dlib68"]


# --------------------------------------------------------------------------- sparse layouts (dlib 68, ETH-XGaze 50)


def _dlib68_mirror() -> list[int]:
    """dlib's left-right partner of each of its 68 points, written out from the layout's definition."""
    m = list(range(68))
    for i in range(17):
        m[i] = 16 - i  # jaw
    for i in range(10):
        m[17 + i] = 26 - i  # eyebrows
    for i in range(5):
        m[31 + i] = 35 - i  # nostrils
    pairs = [(36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46)]  # eyes
    pairs += [(48, 54), (49, 53), (50, 52), (55, 59), (56, 58), (60, 64), (61, 63), (65, 67)]  # lips
    for a, b in pairs:
        m[a], m[b] = b, a
    return m


def test_dlib68_map_commutes_with_the_mirror_and_keeps_the_key_points():
    from facemesh.face_models import KEYPOINTS
    from facemesh.face_models.layouts import DLIB68_TO_ETH50, MEDIAPIPE_TO_DLIB68, MEDIAPIPE_TO_ETH50

    m68 = np.asarray(MEDIAPIPE_TO_DLIB68)
    assert len(m68) == 68 and len(set(m68.tolist())) == 68 and m68.max() < 468
    mirror = mirror_permutation()
    assert [int(mirror[m68[i]]) for i in range(68)] == [int(m68[j]) for j in _dlib68_mirror()]
    # the dlib key points are MediaPipe's eye and mouth corners
    mp, dl = KEYPOINTS["mediapipe"], KEYPOINTS["dlib68"]
    assert [int(m68[i]) for i in dl.face_indices] == list(mp.face_indices)
    # ETH-XGaze's 50: the chin, then dlib 17-59 and the inner lips but their corners
    assert DLIB68_TO_ETH50 == (8, *range(17, 60), 61, 62, 63, 65, 66, 67)
    eth = KEYPOINTS["eth50"]
    assert [DLIB68_TO_ETH50[i] for i in eth.face_indices] == list(dl.face_indices)
    assert MEDIAPIPE_TO_ETH50 == tuple(int(m68[i]) for i in DLIB68_TO_ETH50)


def test_eth50_subset_fits_eth_xgazes_own_face_model(shared_data):
    """ETH-XGaze's face model (another face, its own frame) against the built-in model at the mapped
    indices: a similarity fit within 6 mm RMS, and dropping the inner mouth corners (60, 64) fits
    better than dropping any other symmetric pair: the 50 rows are what the map says."""
    from facemesh.face_models.layouts import MEDIAPIPE_TO_DLIB68

    path = shared_data / "gaze" / "calibrations" / "eth_xgaze_face_model.txt"
    eth = np.loadtxt(path)
    assert eth.shape == (50, 3)
    v = builtin_face_model().vertices_mm[np.asarray(MEDIAPIPE_TO_DLIB68)]

    def rms_without(pair):
        keep = [8] + [i for i in range(17, 68) if i not in pair]
        return _rms_after_similarity(v[keep], eth)

    best = rms_without((60, 64))
    assert best < 6.0
    others = [(48, 54), (61, 63), (65, 67), (49, 53), (55, 59), (62, 66)]
    assert all(best < rms_without(p) for p in others)


def test_sparse_face_model_takes_the_built_in_points():
    from facemesh.face_models.layouts import sparse_face_model
    from facemesh.types import InputError

    model, idx = sparse_face_model("dlib68")
    assert model.num_points == 68 and model.triangles is None and model.keypoints is not None
    assert np.array_equal(model.vertices_mm, builtin_face_model().vertices_mm[idx])
    with pytest.raises(InputError, match="layout"):
        sparse_face_model("dlib5")


def test_derive_mediapipe_writes_the_packaged_file_only_when_asked(capsys):
    """Without -o or --write-packaged the derivation refuses (exit 2) before any work, and the shipped file stays."""
    from facemesh.face_models import derive_mediapipe

    before = derive_mediapipe.PACKAGED_MODEL.read_bytes()
    with pytest.raises(SystemExit) as exc:
        derive_mediapipe.main([])
    assert exc.value.code == 2
    assert "--output" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        derive_mediapipe.main(["-o", "x.npz", "--write-packaged"])
    assert derive_mediapipe.PACKAGED_MODEL.read_bytes() == before
