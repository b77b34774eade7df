"""tools/dc4gs_decisions.py: the known-geometry probe finds the built-in ground's checker edge where it lies on
a Gaussian's axis and none inside a tile; a short run's report accounts for every candidate."""
import json

import numpy as np

from dc4gs_cl.scene import builtin
from helpers import load_tool

decisions = load_tool("dc4gs_decisions")


def test_axis_profile_finds_the_checker_edge():
    """Ground tiles are 0.5 wide: a Gaussian at x = 3 + s along x (sigma s' = 0.1) crosses the edge x = 3 at
    -s / 0.1 sigma; one inside the tile [3, 3.5] crosses none."""
    rng = np.random.default_rng()
    offset = rng.uniform(-0.15, 0.15)            # the next edges, x = 2.5 and 3.5, stay off the axis
    means = np.array([[3.0 - offset, 3.25, 0.0], [3.25, 3.25, 0.0]])
    steps, seen = decisions.axis_profiles(means, np.array([0.1, 0.07]), np.array([[1.0, 0, 0], [1.0, 0, 0]]),
                                          builtin.builtin_scene(resolution=4).train)
    assert (seen > 0).all()
    at = (np.arange(decisions.SAMPLES - 1) + 0.5) * 6 / (decisions.SAMPLES - 1) - 3
    edges = at[steps[0] >= decisions.EDGE_STEP]
    assert len(edges) == 1 and abs(edges[0] - offset / 0.1) <= 0.1
    assert steps[1].max() < decisions.EDGE_STEP


def test_short_run_accounts_for_every_candidate(tmp_path):
    assert decisions.main(["--iterations", "60", "-r", "4", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "decisions.json").read_text())
    assert len(report["steps"]) >= 3 and report["strategy"] == "absgs+DC4GS"
    for s in report["steps"]:
        # DCC's criterion is the base's times (1 - kappa): it never splits what the base would not
        assert s["split"] + s["withheld"] == s["candidates"] and s["split_not_candidates"] == 0
        assert all(0 <= q <= 1 for q in s["one_minus_kappa_quartiles"])
        assert len(s["cut_to_edge"]) == len(s["middle_to_edge"]) == len(s["uniform_to_edge"]) <= s["split"]
    assert any(s["withheld"] > 0 for s in report["steps"]) and any(s["cut_to_edge"] for s in report["steps"])
    assert "## Known geometry" in (tmp_path / "decisions.md").read_text()
    assert (tmp_path / report["panels"]).stat().st_size > 5_000
