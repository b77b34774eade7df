"""Camera paths (scene/paths.py) and `render --path`: the interpolated path passes through the training cameras,
the orbit circles the point they look at, looking at it; frames and a video are written, or a line says why not."""
import shutil

import numpy as np
import pytest

from dc4gs_cl import geometry
from dc4gs_cl.cli import main
from dc4gs_cl.errors import InputError
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.camera import Camera
from dc4gs_cl.scene.images import read_image
from dc4gs_cl.scene.paths import camera_path, look_at_point


def random_rotation(rng) -> np.ndarray:
    return geometry.quat_to_rotmat(rng.normal(size=(1, 4)))[0]


def test_quaternions_of_rotations_and_their_interpolation(rng):
    for _ in range(200):   # every branch of Shepperd's method
        R = random_rotation(rng)
        q = geometry.rotmat_to_quat(R)
        assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        np.testing.assert_allclose(geometry.quat_to_rotmat(q[None])[0], R, atol=1e-12)
    q0, q1 = geometry.rotmat_to_quat(random_rotation(rng)), geometry.rotmat_to_quat(random_rotation(rng))
    np.testing.assert_allclose(geometry.slerp(q0, q1, 0.0), q0, atol=1e-12)
    assert abs(abs(geometry.slerp(q0, q1, 1.0) @ q1) - 1) < 1e-12
    half = geometry.slerp(q0, q1, 0.5)
    assert abs(np.linalg.norm(half) - 1) < 1e-12 and abs(abs(half @ q0) - abs(half @ q1)) < 1e-12   # halfway
    np.testing.assert_allclose(geometry.slerp(q0, q0, 0.3), q0, atol=1e-12)


def test_the_interpolated_path_passes_through_the_training_cameras():
    cams = load_scene("builtin", resolution=4).train
    steps = 3
    path = camera_path(cams, "interpolated", (len(cams) - 1) * steps + 1)
    for i, cam in enumerate(sorted(cams, key=lambda c: c.name)):
        frame = path[i * steps]
        np.testing.assert_allclose(frame.R, cam.R, atol=1e-9)
        np.testing.assert_allclose(frame.center, cam.center, atol=1e-9)
        assert (frame.width, frame.height) == (cams[0].width, cams[0].height) and frame.fx == pytest.approx(cam.fx)
    steps_between = [np.linalg.norm(a.center - b.center) for a, b in zip(path, path[1:])]
    assert max(steps_between) < 3 * np.median(steps_between)   # smooth: no jumps


def test_the_orbit_circles_the_point_the_cameras_look_at():
    cams = load_scene("builtin", resolution=4).train
    target = look_at_point(cams)
    for cam in cams[:5]:   # the built-in ring looks at one point
        to_target = target - cam.center
        assert np.linalg.norm(np.cross(cam.R[2], to_target)) / np.linalg.norm(to_target) < 0.05
    path = camera_path(cams, "orbit", 24)
    distances = [np.linalg.norm(c.center - target) for c in path]
    assert np.ptp(distances) < 1e-9 * max(distances)
    for c in path:
        direction = (target - c.center) / np.linalg.norm(target - c.center)
        np.testing.assert_allclose(c.R[2], direction, atol=1e-9)   # looking at it
    first = sorted(cams, key=lambda c: c.name)[0]
    assert np.dot(path[0].center - target, first.center - target) > 0   # starting on the first camera's side


def test_a_path_needs_two_cameras_and_two_frames():
    cam = Camera.look_at("a", (3.0, 0, 0), (0, 0, 0), 64, 48, 1.0)
    with pytest.raises(InputError, match="at least two training cameras"):
        camera_path([cam], "orbit", 10)
    with pytest.raises(InputError, match="--frames 1 must be at least 2"):
        camera_path([cam, cam], "interpolated", 1)


@pytest.mark.parametrize("ffmpeg", [True, False], ids=["ffmpeg", "no-ffmpeg"])
def test_render_path_writes_frames_and_a_video(tmp_path, capsys, monkeypatch, ffmpeg):
    if ffmpeg and shutil.which("ffmpeg") is None:
        pytest.skip("ffmpeg is not on PATH: the video is not made (the frames are)")
    if not ffmpeg:
        monkeypatch.setattr(shutil, "which", lambda name: None)
    out = tmp_path / "out"
    assert main(["render", "--out", str(out), "-r", "4", "--path", "orbit", "--frames", "8", "--fps", "4"]) == 0
    frames = sorted((out / "path-orbit").glob("*.png"))
    assert [f.name for f in frames] == [f"{i:05d}.png" for i in range(8)]
    assert read_image(frames[0]).shape == (36, 48, 3)
    video = out / "path-orbit.mp4"
    err = capsys.readouterr().err
    if ffmpeg:
        assert video.read_bytes()[4:8] == b"ftyp" and f"wrote {video}" in err
    else:
        assert not video.exists() and "no ffmpeg on PATH" in err
    assert sorted(p.name for p in out.iterdir()) == ["path-orbit"] + (["path-orbit.mp4"] if ffmpeg else [])


def test_render_path_bad_input_is_one_line(tmp_path, capsys):
    for args, says in ((["--frames", "1"], "--frames 1 must be at least 2"), (["--fps", "0"], "--fps 0 must be")):
        assert main(["render", "--out", str(tmp_path / "out"), "-r", "8", "--path", "interpolated", *args]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "out").exists()


def test_a_path_is_bounded_and_its_memory_does_not_grow_with_its_frames():
    """render --path --frames 1000000000 took 8 GB in 30 s before writing a frame."""
    import tracemalloc

    from dc4gs_cl.scene.paths import MAX_PATH_FRAMES
    cams = load_scene("builtin", resolution=8).train
    with pytest.raises(InputError, match=f"at most {MAX_PATH_FRAMES:,}"):
        camera_path(cams, "orbit", 1_000_000_000)
    for kind in ("interpolated", "orbit"):
        tracemalloc.start()
        try:
            path = camera_path(cams, kind, MAX_PATH_FRAMES)
            last = path[-1]
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert len(path) == MAX_PATH_FRAMES and last.name == f"{MAX_PATH_FRAMES - 1:05d}" and peak < 2**20, peak


def test_an_orbit_around_a_point_behind_the_cameras_is_told():
    """The orbit of cameras that look at no common point rendered black frames with no warning: cameras_behind
    tells render --path orbit to warn (cameras on a ring looking outwards: the least-squares point is behind all)."""
    from dc4gs_cl.scene.paths import cameras_behind
    ring = [Camera.look_at(f"{i}", (3 * np.cos(a), 3 * np.sin(a), 0.0), (6 * np.cos(a), 6 * np.sin(a), 0.0), 64, 48,
                           1.0) for i, a in enumerate(np.linspace(0, 2 * np.pi, 8, endpoint=False))]
    assert cameras_behind(ring, look_at_point(ring)) == len(ring)
    inward = load_scene("builtin", resolution=8).train
    assert cameras_behind(inward, look_at_point(inward)) == 0

