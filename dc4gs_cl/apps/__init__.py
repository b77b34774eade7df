"""The commands, each a module with its arguments that cli.py dispatches to: training (train), evaluation
(evaluation), rendering (render, and video for render --path), the browser viewer (viewer), the metrics report
(report), the exports for other viewers (export/) and the benchmark (bench); render, view and export read their
model through model_source. All but bench import without OpenCL (tests/test_structure.py)."""
