"""The commands beyond training and evaluation, each a module cli.py dispatches to: the browser viewer (viewer),
the metrics report (report), the exports for other viewers (export/) and the benchmark (bench). All but bench
import without OpenCL (tests/test_structure.py)."""
