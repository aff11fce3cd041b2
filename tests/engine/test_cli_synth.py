"""``codev synth``'s human output on every bundled example and on laws over theta.

A law with input rates (``Rd``, ``du_min`` / ``du_max``) or a free reference is over
``theta = (x, u_prev, r)``, longer than the state: the region lines name its parameters
(``prev_<input>``, ``ref_<...>``), and nothing crashes after ``--out`` is written. The
horizons are cut to 2 to keep this fast (the output, not the law, is under test).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import codev_engine as ce
from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))

#: the double integrator, with what each case adds to its [mpc] table
BASE = """
name = "t"
[plant]
states = ["p", "v"]
inputs = ["u"]
A = [[0.0, 1.0], [0.0, 0.0]]
B = [[0.0], [1.0]]
[model]
sample_time = 0.2
[mpc]
horizon = 2
norm = "{norm}"
Q = [[1.0, 0.0], [0.0, 1.0]]
R = [[0.5]]
x_min = [-5.0, -2.0]
x_max = [5.0, 2.0]
u_min = [-1.0]
u_max = [1.0]
{extra}
"""

REF_Y = 'C = [[1.0, 0.0]]\n[mpc.reference]\nsignal = "y"\nlower = [-1.0]\nupper = [1.0]'
REF_X = '[mpc.reference]\nsignal = "x"\nlower = [-1.0, 0.0]\nupper = [1.0, 0.0]'
CASES = {
    "Rd": ("Rd = [[1.0]]", ("p", "v", "prev_u")),
    "du": ("du_min = [-0.3]\ndu_max = [0.3]", ("p", "v", "prev_u")),
    "ref_y": (REF_Y, ("p", "v", "ref_y0")),
    "ref_x": (REF_X, ("p", "v", "ref_p", "ref_v")),
    "ref_fixed": ('[mpc.reference]\nsignal = "x"\nvalue = [0.5, 0.0]', ("p", "v")),
    "rates_and_ref": ("Rd = [[1.0]]\ndu_max = [0.5]\n" + REF_Y, ("p", "v", "prev_u", "ref_y0")),
    "control_horizon": ("control_horizon = 1\ndu_min = [-0.5]", ("p", "v", "prev_u")),
    "soft_output": ('C = [[1.0, 0.0]]\ny_max = [4.0]\nsoft = ["y_max"]\nRd = [[0.2]]',
                    ("p", "v", "prev_u")),
}


def _short(text: str) -> str:
    """The spec with a horizon of 2 (and a control horizon within it)."""
    text = re.sub(r"^horizon = \d+", "horizon = 2", text, flags=re.M)
    return re.sub(r"^control_horizon = \d+", "control_horizon = 2", text, flags=re.M)


def _check_output(out: str, law: ce.ExplicitLaw) -> None:
    assert "critical regions" in out
    names = law.parameter_names
    shown = min(law.num_regions, 5)
    lines = [ln for ln in out.splitlines() if ln.startswith("  region ")]
    assert len(lines) == shown
    for ln in lines:
        for u in law.inputs:
            assert f"{u} = " in ln
        assert all(f"*{nm}" in ln for nm in names), (ln, names)
    if law.n > len(law.states):
        assert f"law over theta = ({', '.join(names)})" in out


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_synth_prints_every_example(path, tmp_path, capsys):
    spec = tmp_path / path.name
    spec.write_text(_short(path.read_text()))
    out = tmp_path / "law.npz"
    assert main(["synth", str(spec), "--out", str(out)]) == 0
    _check_output(capsys.readouterr().out, ce.ExplicitLaw.load(out))


@pytest.mark.parametrize("norm", ["2", "inf"])
@pytest.mark.parametrize("case", list(CASES))
def test_synth_prints_laws_over_theta(case, norm, tmp_path, capsys):
    extra, names = CASES[case]
    spec = tmp_path / "t.toml"
    spec.write_text(BASE.format(norm=norm, extra=extra))
    out = tmp_path / "law.npz"
    assert main(["synth", str(spec), "--out", str(out)]) == 0
    law = ce.ExplicitLaw.load(out)
    assert law.parameter_names == names
    _check_output(capsys.readouterr().out, law)


def test_other_consumers_name_theta(tmp_path):
    """The picture and the notebook summary of a law over theta name its parameters; a
    law file's free-text problem name is drawn as text (a '$' is not mathtext)."""
    from codev_engine.view import figures

    extra, names = CASES["rates_and_ref"]
    law = ce.synthesize(ce.loads_spec(BASE.format(norm="inf", extra=extra)))
    ax = figures.plot_partition(law)
    assert (ax.get_xlabel(), ax.get_ylabel()) == names[:2]
    assert "prev_u = " in ax.get_title() and "ref_y0 = " in ax.get_title()
    html = figures.law_html(law, png=b"")
    assert "2 (p, v)" in html and "4 (p, v, prev_u, ref_y0)" in html
    law.meta["problem"] = "$\\frac{$"
    assert figures.png_bytes(figures.figure_law(law))
