"""The expected cost of an export on given states (``deploy.expected``) and ``auto``'s
choice by it (issue 39: the region of operation's sequential search checks the tube's
region first).

- the rows ``expected_rows`` counts are those the generated Python code evaluates (its
  ``_row`` counted) plus the node tests on the path, for both searches, on random states;
- ``plan(..., states=...)`` picks the search of fewer rows at the mean on them, and keeps
  each search's certified worst case.
"""

from __future__ import annotations

import numpy as np

import codev_engine as ce
from codev_engine.deploy.expected import expected_rows
from codev_engine.deploy.export import export_python
from codev_engine.deploy.plan import plan
from tests.conftest import EXAMPLES_DIR as EXAMPLES
from tests.engine.test_export import _load_module


def _counted(mod, ex, X: np.ndarray) -> np.ndarray:
    """Rows the generated module evaluates per state, plus the tree's tests on the path."""
    calls = [0]
    row = mod._row

    def counting(j, x):
        calls[0] += 1
        return row(j, x)

    mod._row = counting
    out = []
    t = ex.tree
    for x in X:
        calls[0] = 0
        mod.locate(x)
        k, tests = (0 if t.num_nodes else -1), 0
        while k >= 0:
            tests += 1
            k = int(t.node_next[k][1 if float(t.node_a[k] @ x - t.node_b[k]) > 0 else 0])
        out.append(calls[0] + tests)
    return np.array(out)


def test_expected_rows_count_the_generated_codes_evaluations(tmp_path):
    law = ce.synthesize(ce.load_spec(EXAMPLES / "double_integrator.toml"))
    rng = np.random.default_rng(0)
    blo, bhi = law.boxes
    X = rng.uniform(blo.min(axis=0), bhi.max(axis=0), (60, law.n))
    X = X[law.locate(X) >= 0]
    assert X.shape[0] > 10
    for method in ("bst", "sequential"):
        ex = plan(law, method)
        mod = _load_module(export_python(ex, tmp_path / f"e_{method}.py"))
        np.testing.assert_array_equal(
            expected_rows(ex.tree, ex.dep.A, ex.dep.b, ex.dep.off, X), _counted(mod, ex, X))


def test_auto_chooses_by_the_mean_on_the_states_given():
    law = ce.synthesize(ce.load_spec(EXAMPLES / "double_integrator.toml"))
    both = {m: plan(law, m) for m in ("bst", "sequential")}
    rng = np.random.default_rng(1)
    blo, bhi = law.boxes
    X = rng.uniform(blo.min(axis=0), bhi.max(axis=0), (400, law.n))
    reg = law.locate(X)
    chosen = set()
    for r in (0, int(reg.max())):  # states in the first region, and in the last
        S = X[reg == r][:20]
        mean = {m: float(expected_rows(e.tree, e.dep.A, e.dep.b, e.dep.off, S).mean())
                for m, e in both.items()}
        ex = plan(law, "auto", states=S)
        assert ex.expected == min(mean.values())
        assert ex.method == min(mean, key=lambda m: (mean[m], both[m].macs))
        assert ex.macs == both[ex.method].macs  # (the certified worst case, unchanged)
        chosen.add(ex.method)
    # (the first region: the sequential search, 4 rows against the tree's 6; the last:
    # the tree, 4 against 28; without states the worst case decides: the tree)
    assert chosen == {"bst", "sequential"}
    assert plan(law, "auto").expected is None
