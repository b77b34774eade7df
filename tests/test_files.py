"""Atomic output (dc4gs_cl/files.py) and per-view output names."""
import numpy as np
import pytest

from dc4gs_cl.files import replace_folder, staging_folder, write_atomic, write_json
from dc4gs_cl.scene.camera import Camera


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "out" / "data.json"
    write_json(path, {"a": 1})

    def fails(tmp):
        tmp.write_text("half")
        raise RuntimeError("disk full")
    with pytest.raises(RuntimeError):
        write_atomic(path, fails)
    assert path.read_text() == '{\n  "a": 1\n}'
    assert [p.name for p in path.parent.iterdir()] == ["data.json"]


def test_a_temporary_name_keeps_the_extension(tmp_path):
    seen = []
    write_atomic(tmp_path / "image.png", lambda tmp: (seen.append(tmp), tmp.write_bytes(b"x")))
    assert seen[0].suffix == ".png" and seen[0].parent == tmp_path and seen[0].name.startswith(".")


def test_replace_folder_swaps_in_the_new_folder_whole(tmp_path):
    final = tmp_path / "renders"
    final.mkdir()
    (final / "old.png").write_bytes(b"old")
    staging = staging_folder(final)
    (staging / "new.png").write_bytes(b"new")
    assert (final / "old.png").exists()            # the old folder stays until the new one is complete
    replace_folder(staging, final)
    assert [p.name for p in final.iterdir()] == ["new.png"]
    assert [p.name for p in tmp_path.iterdir()] == ["renders"]


def test_file_stems_are_unique_across_folders():
    def cam(name):
        return Camera(name, 4, 3, 1.0, 1.0, 2.0, 1.5, np.eye(3), np.zeros(3))
    assert cam("cam1/0001.jpg").file_stem == "cam1_0001"
    assert cam("cam2/0001.jpg").file_stem == "cam2_0001"
    assert cam("r_0").file_stem == "r_0"


@pytest.mark.parametrize("name, stem", [("../../../x/y.png", "x_y"), (".hidden.png", "hidden"),
                                        ("./a/.b/c.jpg", "a_.b_c"), ("..png", "_"), ("/abs/p.png", "abs_p"),
                                        ("..\\..\\w.png", "w")])
def test_no_output_name_is_hidden_or_climbs_out(name, stem):
    """A view named ../../../x/y.png was written as the hidden file .._.._.._x_y.png."""
    assert Camera(name, 4, 3, 1.0, 1.0, 2.0, 1.5, np.eye(3), np.zeros(3)).file_stem == stem


@pytest.mark.parametrize("kind", ["fifo", "folder"])
def test_an_output_never_replaces_what_is_not_a_regular_file(tmp_path, kind):
    """`export --out /dev/full` once printed "bytes written" and replaced the device node with a regular file (the
    atomic rename): a FIFO (here, for a device node) or a folder where a file goes is refused, and left as it was."""
    import os
    import stat

    from dc4gs_cl.errors import OutputError
    path = tmp_path / "out.ply"
    os.mkfifo(path) if kind == "fifo" else path.mkdir()
    with pytest.raises(OutputError, match="not a regular file"):
        write_atomic(path, lambda tmp: tmp.write_bytes(b"model"))
    mode = os.lstat(path).st_mode
    assert stat.S_ISFIFO(mode) if kind == "fifo" else stat.S_ISDIR(mode)
    assert [p.name for p in tmp_path.iterdir()] == ["out.ply"]   # no temporary left


def test_a_folder_of_renders_never_replaces_a_file(tmp_path):
    from dc4gs_cl.errors import OutputError
    final = tmp_path / "renders"
    final.write_bytes(b"a user's file")
    with pytest.raises(OutputError, match="not a folder"):
        staging_folder(final)
    assert final.read_bytes() == b"a user's file" and [p.name for p in tmp_path.iterdir()] == ["renders"]


def test_a_symbolic_link_is_replaced_not_followed(tmp_path):
    elsewhere = tmp_path / "elsewhere.json"
    elsewhere.write_text("kept")
    link = tmp_path / "out.json"
    link.symlink_to(elsewhere)
    write_json(link, {"a": 1})
    assert elsewhere.read_text() == "kept" and not link.is_symlink() and link.read_text() == '{\n  "a": 1\n}'
