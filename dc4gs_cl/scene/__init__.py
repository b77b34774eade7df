"""Scenes: cameras and the train / test split (camera.py), the COLMAP and NeRF readers (colmap.py, nerf.py) and the
loader over them (loader.py: load_scene), images (images.py, OpenImageIO), masks, undistortion (pycolmap), camera
paths (paths.py) and the built-in scene (builtin.py).

This package's own import loads nothing: the names the settings and the command line need (camera.TEST_SPLITS,
builtin.BUILTIN_SCENE, paths.PATH_KINDS) import without pycolmap and OpenImageIO (tests/test_structure.py)."""
