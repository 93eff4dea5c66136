"""The Python baseline finds the scale scenario's chain, and the comparison runs end to end.

Needs numpy, scipy and pytest, and the kinetree binary in $KINETREE_BIN (else on the PATH) to
write the data.
"""

import json
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import compare  # noqa: E402
import paper_baseline  # noqa: E402

KINETREE = os.environ.get("KINETREE_BIN", "kinetree")


def simulate(folder, seed, points=100, frames=200):
    compare.simulate_scale(KINETREE, folder, points, frames, seed)
    truth = json.loads((folder / "truth.json").read_text())
    return np.load(folder / "tracks.npy"), truth


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_baseline_finds_the_scale_scenarios_chain(tmp_path, seed):
    x, truth = simulate(tmp_path, seed)
    bodies, root, joints, times = paper_baseline.discover(x, 0.001)
    owner = np.asarray(truth["point_body"])
    # Each body holds the points of one true body, all of them.
    true_of = []
    for b in bodies:
        found = set(owner[b["points"]])
        assert len(found) == 1, f"body mixes true bodies {found}"
        (t,) = found
        assert len(b["points"]) == int((owner == t).sum())
        true_of.append(int(t))
    assert sorted(true_of) == list(range(len(truth["mechanism"]["bodies"])))
    # The root is the static base, and every joint is a true one, of its type.
    assert true_of[root] == 0
    expected = {(j["parent"], j["child"]): j["type"] for j in truth["mechanism"]["joints"]}
    assert len(joints) == len(expected)
    for j in joints:
        edge = (true_of[j["parent"]], true_of[j["child"]])
        assert expected.get(edge) == j["type"], f"{edge}: {j['type']}"
    assert set(times) == {"pair statistics", "clustering", "poses", "pair tests and tree"}


def test_the_pair_statistics_are_the_direct_sums(tmp_path):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(6, 5, 3))
    x[1, 2] = np.nan
    x[4, 0] = np.nan
    count, total, square = paper_baseline.pair_statistics(x)
    k = 0
    for i in range(5):
        for j in range(i + 1, 5):
            d = [np.linalg.norm(f[i] - f[j]) for f in x if not np.isnan(f[[i, j]]).any()]
            assert count[k] == len(d)
            assert total[k] == pytest.approx(sum(d))
            assert square[k] == pytest.approx(sum(v * v for v in d))
            k += 1


def test_the_comparison_prints_both_times_and_their_ratio(capsys):
    compare.main(["--points", "50", "--frames", "40", "--runs", "1", "--kinetree", KINETREE])
    out = capsys.readouterr().out
    assert "run 1: kinetree" in out
    assert "baseline / kinetree =" in out


def test_the_baseline_refuses_tracks_of_the_wrong_shape(tmp_path):
    bad = tmp_path / "bad.npy"
    np.save(bad, np.zeros((4, 5)))
    with pytest.raises(SystemExit) as e:
        paper_baseline.main([str(bad), "--noise-sigma", "0.001"])
    assert "expected shape (frames, points, 3)" in str(e.value)
