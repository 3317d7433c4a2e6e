"""The T-beam example (examples/ar/tbeam: dots on a web under a flange): which dots the project pipeline
searches in a frame, against trimesh's ray casting of the example's STL surface (an independent surface and
ray caster): a dot is searched only when the camera sees its face and all of it (centre and rim)."""
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from physar.ar.project import load_project
from physar.ar.project_pipeline import RIM_FRACTION, ProjectPipeline
from physar.vision.camera import Pose

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "ar" / "tbeam"


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    d = tmp_path_factory.mktemp("tbeam")
    for f in ("project.toml", "rom.toml", "tbeam.stl"):
        shutil.copy(EXAMPLE / f, d / f)
    shutil.copy(EXAMPLE.parents[1] / "camera_720p.toml", d / "camera.toml")
    (d / "project.toml").write_text((d / "project.toml").read_text().replace("../../camera_720p.toml",
                                                                             "camera.toml"))
    return ProjectPipeline(load_project(d / "project.toml"), overlay=False)


def _eye(elevation, azimuth=-60.0, distance=0.45, target=(0.15, 0.0, 0.01)):
    a, e = np.radians(azimuth), np.radians(elevation)
    return np.asarray(target) + distance * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _seen(mesh, pose, X, normals, radius, eps):
    """Reference: the dot's face turned towards the camera (as the pipeline's cos > 0.15) and no hit of the rays
    from the camera centre to its centre and 8 rim points nearer than the point by more than eps."""
    centre = pose.inverse().t
    view = X - centre
    cos = -np.einsum("ij,ij->i", normals, view / np.linalg.norm(view, axis=1, keepdims=True))
    ray = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    out = cos > 0.15
    for k in np.flatnonzero(out):
        n = normals[k]
        e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        th = np.arange(8) * np.pi / 4
        P = np.vstack([X[k], X[k] + radius * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)])
        d = P - centre
        dist = np.linalg.norm(d, axis=1)
        loc, idx, _ = ray.intersects_location(np.tile(centre, (len(P), 1)), d / dist[:, None], multiple_hits=True)
        depth = pose.apply(loc)[:, 2] if len(loc) else np.zeros(0)
        pz = pose.apply(P)[:, 2]
        out[k] = not np.any(depth < pz[idx] - eps)
    return out


@pytest.mark.parametrize("elevation", [35.0, 12.0, 3.0, -8.0])
def test_dots_hidden_by_the_flange_are_not_searched(pipeline, elevation):
    """At rest, seen from above the beam's side as in the example's scenario (35 deg: the flange hides the top
    of every web dot, their centres still in view), lower (12 and 3 deg: the flange's top face turned away) and
    from below the flange (-8 deg): the dots the pipeline searches are those the reference sees. Catches: no
    occlusion test, the centre only (the web dots under the flange searched at 35 deg: their blobs' centroids
    were 1.2-1.8 px off in the reviewer's clip), the surface taken in the world frame instead of the camera's."""
    pl = pipeline
    mesh = trimesh.load(EXAMPLE / "tbeam.stl")
    pose = Pose.look_at(_eye(elevation), [0.15, 0.0, 0.02])
    c = np.zeros(pl.rom.n_modes)
    got, _ = pl._expected(pose, pl.dots, c)
    ref = _seen(mesh, pose, pl.dots, pl.normals, RIM_FRACTION * pl.radius_m, 0.25 * pl.radius_m)
    web = np.abs(pl.dots[:, 1] + 0.0025) < 1e-9
    assert got.tolist() == ref.tolist(), (elevation, np.flatnonzero(got != ref))
    if elevation == 35.0:
        assert not got[web].any() and got[~web].all()
    if elevation == -8.0:
        assert got[web].all() and not got[~web].any()


def test_hidden_dots_follow_the_deformed_surface(pipeline):
    """Load at the tip (tip 4 mm down): seen from above, the flange's dots on the deformed surface are searched
    (the rest surface would hide those near the tip: they lie inside its flange), the web's are not; from a
    tenth of the load's ray casting on the model's deformed surface by trimesh. Catches: the rest surface used
    with deformed dots, the mode coefficients ignored."""
    pl = pipeline
    mu = np.array([pl.hi[0]])
    c = pl.rom.coefficients(mu)[0]
    X = pl.dot_positions(mu)
    assert (X - pl.dots)[:, 2].min() < -3e-3                              # the tip dots move 3+ mm down
    surf = pl.rom.space().mesh.boundary()
    S = surf.mesh.points + np.tensordot(c, pl._occ_U, 1)
    mesh = trimesh.Trimesh(S, surf.mesh.faces, process=False)
    pose = Pose.look_at(_eye(40.0), [0.15, 0.0, 0.02])
    got, _ = pl._expected(pose, X, c)
    ref = _seen(mesh, pose, X, pl.normals, RIM_FRACTION * pl.radius_m, 0.25 * pl.radius_m)
    assert got.tolist() == ref.tolist(), np.flatnonzero(got != ref)
    top = pl.dots[:, 2] > 0.034
    assert got[top].all() and not got[~top].any()
    rest, _ = pl._expected(pose, X, np.zeros_like(c))                  # the mutant: the rest surface
    assert not rest[top].all()


@pytest.mark.parametrize("joint", [True, False])
def test_reported_std_covers_the_pose_uncertainty(pipeline, monkeypatch, joint):
    """Monte Carlo (200 frames of exact dot and marker-corner pixels plus Gaussian noise of the project's
    dot_sigma_px and corner_sigma_px, the pose from the noisy corners by OpenCV's solvePnP): the std the solve
    reports matches the spread of its estimates within 15 %, with the pose refined together with s and with
    ``joint_pose = false`` (the pose held at the markers'). Catches: the held pose's own uncertainty left out of
    s's std (reported 3.13 mm against a spread of 4.52 mm, 31 % too small)."""
    import cv2

    from physar.vision.markers import PoseEstimate

    pl = pipeline
    monkeypatch.setattr(pl.project.tracking, "joint_pose", joint)
    trk = pl.project.tracking
    pose = Pose.look_at(_eye(35.0), [0.15, 0.0, 0.02])
    mu = np.array([0.15])
    X = pl.dot_positions(mu)
    vis, _ = pl._expected(pose, X, pl.rom.coefficients(mu)[0])
    q = pl.camera.project(X, pose)
    C = pl.board.corners.reshape(-1, 3)
    qc = pl.camera.project(C, pose)
    K, dist = pl.camera.to_opencv()
    rng = np.random.default_rng(0)
    est, std = [], []
    for _ in range(200):
        c = qc + rng.normal(0, trk.corner_sigma_px, qc.shape)
        _, rv, tv = cv2.solvePnP(C, c, K, dist, flags=cv2.SOLVEPNP_SQPNP)
        rv, tv = cv2.solvePnPRefineLM(C, c, K, dist, rv, tv)
        pe = PoseEstimate(Pose.from_rvec(rv.ravel(), tv.ravel()), "measured", len(pl.board.ids),
                          trk.corner_sigma_px, [int(i) for i in pl.board.ids], c)
        m, s, *_ = pl._solve(pe, q + rng.normal(0, trk.dot_sigma_px, q.shape), vis, mu)
        est.append(m[0])
        std.append(s[0])
    ratio = np.mean(std) / np.std(est)
    assert 0.85 < ratio < 1.15, (ratio, np.mean(std), np.std(est))


def test_a_dot_placed_inside_the_surface_is_still_searched(pipeline, tmp_path):
    """The flange's first five dots written 0.6 mm inside it (the file allows [dots] tol = diameter / 4 = 1 mm):
    they are searched where trimesh's ray casting sees the same dots on the face (35 deg from above, and straight
    down), since the test points are their closest points on the surface. Catches: the points tested where the file puts them
    (the dots' own face hides them: never searched)."""
    for f in ("rom.toml", "tbeam.stl"):
        shutil.copy(EXAMPLE / f, tmp_path / f)
    shutil.copy(EXAMPLE.parents[1] / "camera_720p.toml", tmp_path / "camera.toml")
    text = (EXAMPLE / "project.toml").read_text().replace("../../camera_720p.toml", "camera.toml")
    inside = text.replace("[[0.06, -0.012, 0.035], [0.12, -0.012, 0.035], [0.18, -0.012, 0.035], [0.24, -0.012, 0.035],\n"
                          "          [0.29, -0.012, 0.035],",
                          "[[0.06, -0.012, 0.0344], [0.12, -0.012, 0.0344], [0.18, -0.012, 0.0344], "
                          "[0.24, -0.012, 0.0344],\n          [0.29, -0.012, 0.0344],")
    assert inside != text
    (tmp_path / "project.toml").write_text(inside)
    pl = ProjectPipeline(load_project(tmp_path / "project.toml"), overlay=False)
    c = np.zeros(pl.rom.n_modes)
    mesh = trimesh.load(EXAMPLE / "tbeam.stl")
    for eye in (_eye(35.0), [0.15, -0.001, 0.5]):
        pose = Pose.look_at(eye, [0.15, 0.0, 0.02])
        got, _ = pl._expected(pose, pl.dots, c)
        # reference: trimesh's ray casting of the STL at the dots' places on the face (the example's dots)
        ref = _seen(mesh, pose, pipeline.dots, pl.normals, RIM_FRACTION * pl.radius_m, 0.25 * pl.radius_m)
        assert got.tolist() == ref.tolist(), (eye, got, ref)
        assert got[:5].all()


def test_frames_where_the_object_hides_the_dots_are_counted_and_named(tmp_path, monkeypatch):
    """A project with only the web's six dots, filmed from above (35 deg): every dot faces the camera but the
    flange hides it, so each frame holds; the run's summary counts those frames and one warning says the
    object itself hid the dots (the CLI's "no frame was tracked" line otherwise blamed the [dots] settings).
    Seen from below the flange (-8 deg) the same frames are not counted. Catches: frames hidden by the object
    not counted, a frame whose dots are in view but not found counted as hidden."""
    import av

    from physar.vision.markers import PoseEstimate

    for f in ("rom.toml", "tbeam.stl"):
        shutil.copy(EXAMPLE / f, tmp_path / f)
    shutil.copy(EXAMPLE.parents[1] / "camera_720p.toml", tmp_path / "camera.toml")
    text = (EXAMPLE / "project.toml").read_text().replace("../../camera_720p.toml", "camera.toml")
    start = text.index("points = [[0.06")
    end = text.index("[0.05, -0.0025, 0.015]")
    (tmp_path / "project.toml").write_text(text[:start] + "points = [" + text[end:])
    video = tmp_path / "grey.mp4"
    with av.open(str(video), "w") as out:
        s = out.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = 1280, 720, "yuv420p"
        for _ in range(4):
            for pkt in s.encode(av.VideoFrame.from_ndarray(np.full((720, 1280, 3), 128, np.uint8), format="bgr24")):
                out.mux(pkt)
        for pkt in s.encode():
            out.mux(pkt)
    counts = {}
    for elevation in (35.0, -8.0):
        pl = ProjectPipeline(load_project(tmp_path / "project.toml"), overlay=False)
        assert len(pl.dots) == 6
        pe = PoseEstimate(Pose.look_at(_eye(elevation), [0.15, 0.0, 0.02]), "measured", 4, 0.1)
        monkeypatch.setattr(pl.registration, "update", lambda gray, pe=pe: pe)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            summary = pl.run(video)
        counts[elevation] = summary["hidden_frames"]
        named = [str(w.message) for w in caught if "the object itself hid the dots" in str(w.message)]
        assert len(named) == (1 if elevation == 35.0 else 0), named
        if named:
            assert named[0].startswith(f"{tmp_path / 'project.toml'}: in 4 of 4 frames"), named[0]
    assert counts == {35.0: 4, -8.0: 0}
