"""Rerun recordings (codev_engine.view.records): real .rrd files written and read back.

Every recording here is read back with rerun's own ``RrdReader``: entity paths, instance
counts, the ``time`` timeline against the tube's ``t_start``, the blueprint store; plus the
file checks (``check_recording``), the atomic write, and the unsafe margin. (The vertex
enumeration is tested in test_vertices.py.)
"""

from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
import rerun as rr
from rerun.chunk import RrdReader
from rerun.error_utils import strict_mode
from rerun_bindings import check_for_rrd_footer

import codev_engine as ce
from codev_engine.reach.tube import Tube
from codev_engine.reach.verification import VerificationResult
from codev_engine.spec.problem import SetSpec
from codev_engine.view import records
from codev_engine.view.record_content import unsafe_margin
from codev_engine.view.records import (
    RecordingOptions,
    RecordingSummary,
    check_recording,
    write_recording,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DI_TEXT = (EXAMPLES / "double_integrator.toml").read_text()
# the double integrator with an unsafe box around the origin, which the loop converges to
UNSAFE_TEXT = (
    DI_TEXT.split("[[verify.safe]]")[0]
    + "\n[[verify.unsafe]]\nlower = [-1.0, -1.0]\nupper = [1.0, 1.0]\n"
)


# ---------------------------------------------------------------------------------------
# reading a recording back
# ---------------------------------------------------------------------------------------


class Entity:
    """What a recording holds at one entity path (all its chunks)."""

    def __init__(self) -> None:
        self.static = False
        self.rows = 0
        self.times: list[np.ndarray] = []  # ns, one per temporal row
        self.columns: dict[str, list[pa.Array]] = defaultdict(list)

    def instances(self, column: str) -> int:
        """Instances of a component over all rows (sum of the list lengths)."""
        return int(sum(pc.sum(c.value_lengths()).as_py() or 0 for c in self.columns[column]))

    def values(self, column: str) -> np.ndarray:
        """All instances of a component, flattened to rows of numbers."""
        parts = []
        for c in self.columns[column]:
            flat = c.flatten()
            parts.append(np.asarray(flat.to_pylist(), dtype=float))
        return np.concatenate(parts) if parts else np.zeros(0)

    def per_row(self, column: str) -> list:
        return [v for c in self.columns[column] for v in c.to_pylist()]

    @property
    def time(self) -> np.ndarray:
        return np.concatenate(self.times) if self.times else np.zeros(0, dtype=np.int64)


def read(path: Path) -> dict[str, Entity]:
    """Entity path -> Entity, from the recording store of ``path``."""
    out: dict[str, Entity] = defaultdict(Entity)
    for chunk in RrdReader(path).stream().to_chunks():
        e = out[chunk.entity_path]
        rb = chunk.to_record_batch()
        e.static |= chunk.is_static
        e.rows += chunk.num_rows
        if "time" in chunk.timeline_names:
            e.times.append(rb.column("time").cast(pa.int64()).to_numpy())
        for name in rb.schema.names:
            if ":" in name:
                e.columns[name].append(rb.column(name))
    return dict(out)


def view_names(path: Path) -> list[str]:
    """Display names of the views of the blueprint store."""
    reader = RrdReader(path)
    names = []
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            if "ViewBlueprint:display_name" in rb.schema.names:
                for v in rb.column("ViewBlueprint:display_name").to_pylist():
                    names += v or []
    return names


def ns(t: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def no_leftovers(folder: Path) -> bool:
    return not any(p.name.startswith(".tmp-") for p in folder.iterdir())


# ---------------------------------------------------------------------------------------
# fixtures
# ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def di():
    problem = ce.loads_spec(DI_TEXT)
    law = ce.synthesize(problem)
    return problem, law, ce.verify(problem, law)


@pytest.fixture(scope="module")
def di_recording(di, tmp_path_factory):
    problem, law, result = di
    before = (rr.get_global_data_recording(), rr.get_thread_local_data_recording(), strict_mode())
    path = tmp_path_factory.mktemp("di") / "sub" / "di.rrd"
    summary = write_recording(path, problem, law, result)
    after = (rr.get_global_data_recording(), rr.get_thread_local_data_recording(), strict_mode())
    assert before == after  # no global rerun state changed
    return summary, read(path)


@pytest.fixture(scope="module")
def magnetic():
    problem = ce.load_spec(EXAMPLES / "magnetic_pointer_a.toml")
    law = ce.synthesize(problem)  # ~1000 regions in 3-D, about a second
    return problem, law


@pytest.fixture(scope="module")
def unsafe_case(tmp_path_factory):
    problem = ce.loads_spec(UNSAFE_TEXT)
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    path = tmp_path_factory.mktemp("cex") / "cex.rrd"
    summary = write_recording(path, problem, law, result, options=RecordingOptions(traces=4))
    return problem, law, result, summary, read(path)


# ---------------------------------------------------------------------------------------
# the double integrator (2-D, robustly safe)
# ---------------------------------------------------------------------------------------


def test_summary_is_consistent(di, di_recording):
    problem, law, result = di
    summary, entities = di_recording
    assert isinstance(summary, RecordingSummary)
    assert summary.path.is_file() and summary.path.name == "di.rrd"
    assert no_leftovers(summary.path.parent)
    assert summary.boxes == result.tube.num_boxes > 0
    assert summary.traces == RecordingOptions().traces == 16
    assert summary.seconds > 0
    assert set(summary.entities) <= set(entities)
    check_recording(summary.path)
    assert check_for_rrd_footer(str(summary.path))


def view_kinds(path: Path) -> dict[str, str]:
    """Display name -> view class (``2D``, ``3D``, ``TimeSeries``, ``TextDocument``)."""
    reader = RrdReader(path)
    out = {}
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            if "ViewBlueprint:class_identifier" in rb.schema.names:
                kinds = rb.column("ViewBlueprint:class_identifier").to_pylist()
                names = rb.column("ViewBlueprint:display_name").to_pylist()
                for k, n in zip(kinds, names, strict=True):
                    out[(n or ["?"])[0]] = k[0]
    return out


def segmentation(entities: dict[str, Entity], path: str):
    """(image (H, W), class id -> label, pixel -> true coordinates (scale, translation))."""
    e = entities[path]
    fmt = e.per_row("SegmentationImage:format")[0][0]
    buf = np.asarray(e.per_row("SegmentationImage:buffer")[0][0], dtype=np.uint8)
    dtype = {6: np.uint8, 8: np.uint16}[fmt["channel_datatype"]]
    image = buf.view(dtype).reshape(fmt["height"], fmt["width"])
    ctx = e.per_row("AnnotationContext:context")[0][0]
    labels = {c["class_id"]: c["class_description"]["info"]["label"] for c in ctx}
    scale = np.array(e.per_row("Transform3D:scale")[0][0], dtype=float)
    shift = np.array(e.per_row("Transform3D:translation")[0][0], dtype=float)
    return image, labels, scale, shift


def test_entity_layout(di_recording):
    summary, entities = di_recording
    expected = {
        "/plane",
        "/plane/regions",
        "/plane/edges",
        "/plane/overlay",
        "/plane/axes/ticks",
        "/plane/initial",
        "/plane/safe/0",
        "/plane/tube",
        "/plane/traces",
        "/time/x1/tube/lower",
        "/time/x1/tube/upper",
        "/time/x2/tube/lower",
        "/time/x1/traces/0",
        "/time/x2/traces/15",
        "/scalars/u/u/traces/0",
        "/scalars/u/u/traces/15",
        "/scalars/u/u/bounds/min",
        "/scalars/u/u/bounds/max",
        "/verdict",
    }
    assert expected <= set(entities)
    assert not any(k.startswith("/space/") for k in entities)  # n == 2: no 3-D view
    assert not any("counterexample" in k or "violating_trace" in k for k in entities)
    # no unsafe sets: no margin series
    assert not any(k.startswith("/scalars/unsafe_distance") for k in entities)
    for k in ("/plane/regions", "/plane/traces", "/verdict"):
        assert entities[k].static
    # the plane's transform shows the window as a unit square with y up
    scale = np.array(entities["/plane"].per_row("Transform3D:scale")[0][0])
    assert scale[0] > 0 > scale[1]


def test_state_series_on_the_time_timeline(di, di_recording):
    """Each state's tube bounds and each trace are scalar series on ``time``, and the
    bounds contain every box of the tube."""
    _, _, result = di
    _, entities = di_recording
    tube = result.tube
    for i, s in enumerate(("x1", "x2")):
        lo, hi = entities[f"/time/{s}/tube/lower"], entities[f"/time/{s}/tube/upper"]
        assert lo.instances("Scalars:scalars") == len(lo.time) > 0
        t = lo.time / 1e9
        vlo, vhi = lo.values("Scalars:scalars"), hi.values("Scalars:scalars")
        assert np.array_equal(lo.time, hi.time) and np.all(np.diff(lo.time) >= 0)
        assert t[0] == pytest.approx(tube.t_start.min()) and t[-1] == pytest.approx(9.0)
        # a step function: each box is inside the bounds over its interval (float32 file)
        for k in range(0, tube.num_boxes, 37):
            mid = 0.5 * (tube.t_start[k] + tube.t_end[k])
            j = np.searchsorted(t, mid)  # rows come in (start, end) pairs of an interval
            assert vlo[j] <= tube.lower[k, i] + 1e-5 and vhi[j] >= tube.upper[k, i] - 1e-5
        styles = lo.per_row("SeriesLines:names")
        assert styles == [["tube lower"]]
        tr = entities[f"/time/{s}/traces/0"]
        assert tr.instances("Scalars:scalars") == len(tr.time) > 10
        assert tr.values("Scalars:scalars")[0] == pytest.approx([9.0, -5.0][i], abs=1e-6)


def test_tube_boxes_and_times(di, di_recording):
    _, _, result = di
    summary, entities = di_recording
    tube = result.tube
    e = entities["/plane/tube"]
    assert not e.static
    assert e.instances("Boxes2D:half_sizes") == tube.num_boxes == summary.entities["/plane/tube"]
    assert e.instances("Boxes2D:centers") == tube.num_boxes
    # one row per distinct t_start, each holding the boxes that start then
    times = e.time
    starts, counts = np.unique(tube.t_start, return_counts=True)
    assert np.array_equal(np.sort(times), ns(starts))
    per_row = dict(
        zip(times.tolist(), (len(v) for v in e.per_row("Boxes2D:half_sizes")), strict=True)
    )
    assert [per_row[t] for t in ns(starts).tolist()] == counts.tolist()
    # the boxes themselves: centres +- half sizes give back lower/upper on the plane axes
    c = e.values("Boxes2D:centers").reshape(-1, 2)
    h = e.values("Boxes2D:half_sizes").reshape(-1, 2)
    got = np.unique(np.round(np.hstack([c - h, c + h]), 5), axis=0)
    want = np.unique(np.round(np.hstack([tube.lower, tube.upper]), 5), axis=0)
    assert np.allclose(got, want, atol=1e-4)  # float32 in the file


def test_partition_filled(di, di_recording):
    """The partition is a region-index image: one class per region (labelled ``R<i>``),
    every pixel's centre inside the region it names, every region with area on it."""
    _, law, _ = di
    summary, entities = di_recording
    image, labels, scale, shift = segmentation(entities, "/plane/regions")
    assert summary.entities["/plane/regions"] == law.num_regions
    assert labels[0] and all(labels[i + 1] == f"R{i}" for i in range(law.num_regions))
    H, W = image.shape
    ids = np.unique(image)
    assert set(ids.tolist()) - {0} == set(range(1, law.num_regions + 1))  # all regions show
    rng = np.random.default_rng(0)
    rows, cols = np.nonzero(image)
    pick = rng.choice(rows.size, 2000, replace=False)
    for r, c in zip(rows[pick], cols[pick], strict=True):
        x = shift[:2] + (np.array([c, r]) + 0.5) * scale[:2]
        i = int(image[r, c]) - 1
        assert np.all(law.A[i] @ x <= law.b[i] + 1e-6 * (1 + np.abs(law.b[i])) + 1e-3)
    # outlines on top, without labels
    edges = entities["/plane/edges"]
    assert len(edges.per_row("LineStrips2D:strips")[0]) == law.num_regions
    assert "LineStrips2D:labels" not in edges.columns


def test_traces_and_scalars(di_recording):
    summary, entities = di_recording
    strips = entities["/plane/traces"].per_row("LineStrips2D:strips")[0]
    assert len(strips) == 16
    assert np.allclose(np.array(strips[0])[0], [9.0, -5.0], atol=1e-6)  # the centre first
    assert "LineStrips2D:labels" not in entities["/plane/traces"].columns  # no label each
    u = entities["/scalars/u/u/traces/0"]
    assert len(u.time) == summary.entities["/scalars/u/u/traces/0"] > 0  # + 1 static row
    assert np.all(np.diff(u.time) >= 0) and u.time[-1] == ns(9.0)
    values = u.values("Scalars:scalars")
    assert np.all(np.abs(values) <= 1.0 + 1e-6)  # u_min, u_max
    assert np.allclose(entities["/scalars/u/u/bounds/max"].values("Scalars:scalars"), 1.0)
    assert np.allclose(entities["/scalars/u/u/bounds/min"].values("Scalars:scalars"), -1.0)


def test_verdict_and_blueprint(di, di_recording):
    problem, _, result = di
    summary, entities = di_recording
    text = entities["/verdict"].per_row("TextDocument:text")[0][0]
    assert "ROBUSTLY SAFE" in text and f"| tube boxes | {result.tube.num_boxes} |" in text
    assert "| width at t = 9 s (tube's last box) |" in text
    assert "codev 0." in text and "sha256" in text
    assert "| branches |" in text and "has every property checked" in text
    # the claim, before the sizes: the initial set, each property, the time, the hold
    claim = text[text.index("### the claim"):text.index("### sizes")]
    assert "x1 in [8.99, 9.01], x2 in [-5.01, -4.99]" in claim
    assert "stays inside safe set 0: -10 <= x1 <= 10" in claim
    assert "for all t in [0, 9] s" in claim and "**hold**: continuous" in claim
    assert "**NOT checked**" in claim
    reader = RrdReader(summary.path)
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1
    kinds = view_kinds(summary.path)
    plane = [n for n in kinds if n.startswith("plane")]
    assert len(plane) == 1 and kinds[plane[0]] == "2D"
    assert kinds["verdict"] == "TextDocument"
    assert kinds["u(t), bounds black"] == "TimeSeries"
    states = [n for n in kinds if n.startswith(("x1(t)", "x2(t)"))]
    assert len(states) == 2 and all(kinds[n] == "TimeSeries" for n in states)


# ---------------------------------------------------------------------------------------
# other designs
# ---------------------------------------------------------------------------------------


def test_three_states_magnetic_pointer(magnetic, tmp_path):
    problem, law = magnetic
    result = ce.verify(problem, law)
    summary = write_recording(tmp_path / "mpa.rrd", problem, law, result)
    entities = read(summary.path)
    mesh = entities["/space/regions"]
    assert mesh.static
    V = mesh.values("Mesh3D:vertex_positions").reshape(-1, 3)
    T = mesh.values("Mesh3D:triangle_indices").reshape(-1, 3).astype(int)
    assert T.size and T.max() < V.shape[0]
    assert mesh.instances("Mesh3D:vertex_colors") == V.shape[0]
    # the plane is the section through the initial set's centre: a subset of the regions
    image, labels, scale, shift = segmentation(entities, "/plane/regions")
    assert 0 < summary.entities["/plane/regions"] < law.num_regions
    x3 = 0.5 * (problem.verify.initial_lower[2] + problem.verify.initial_upper[2])
    rows, cols = np.nonzero(image)
    for r, c in list(zip(rows, cols, strict=True))[::997]:
        xy = shift[:2] + (np.array([c, r]) + 0.5) * scale[:2]
        i = int(image[r, c]) - 1
        x = np.array([xy[0], xy[1], x3])
        assert np.all(law.A[i] @ x <= law.b[i] + 1e-3)
    for k in ("/space/tube", "/space/traces", "/space/initial", "/space/safe/0"):
        assert k in entities, k
    assert "/time/x3/tube/upper" in entities
    assert entities["/space/tube"].instances("Boxes3D:half_sizes") == result.tube.num_boxes
    assert view_kinds(summary.path)["state space"] == "3D"


def test_projection_axes(magnetic, tmp_path):
    problem, law = magnetic
    opts = RecordingOptions(axes=(2, 0), traces=0)
    summary = write_recording(tmp_path / "p.rrd", problem, law, None, options=opts)
    entities = read(summary.path)
    box = np.array(entities["/plane/initial"].per_row("LineStrips2D:strips")[0][0])
    lo, hi = problem.verify.initial_lower, problem.verify.initial_upper
    assert np.allclose(box.min(axis=0), [lo[2], lo[0]], atol=1e-6)
    assert np.allclose(box.max(axis=0), [hi[2], hi[0]], atol=1e-6)
    assert "/plane/traces" not in entities and summary.traces == 0
    ticks = entities["/plane/axes/ticks"].per_row("Points2D:labels")[0]
    assert "x3 →" in ticks and "x1 ↑" in ticks


def test_counterexample(unsafe_case):
    problem, _, result, summary, entities = unsafe_case
    assert result.verdict == "unsafe" and result.counterexample is not None
    cex = result.counterexample
    e = entities["/plane/counterexample"]
    strip = np.array(e.per_row("LineStrips2D:strips")[0][0], dtype=float)
    x = np.asarray(cex.trace.x)
    assert np.allclose(strip, x[np.all(np.isfinite(x), axis=1)], atol=1e-5)
    for k in (
        "/time/x1/violating_trace",
        "/time/x2/violating_trace",
        "/plane/counterexample/violation",
        "/scalars/u/u/violating_trace",
        "/scalars/unsafe_distance/violating_trace",
        "/scalars/unsafe_distance/traces/0",
        "/scalars/unsafe_distance/zero",
        "/plane/unsafe/0",
    ):
        assert k in entities, k
    series = entities["/time/x1/violating_trace"]
    assert series.instances("Scalars:scalars") == len(series.time) > 1
    # a colour of its own (0xRRGGBBAA): magenta, not the unsafe sets' red, the bounds'
    # black or the traces' grey
    assert series.values("SeriesLines:colors").tolist() == [0xDC00AAFF]
    # on top: the viewer draws a view's series in the order of their paths, the last on
    # top; "counterexample" sorted before "traces" and "tube" (hidden in navigation)
    for k in [k for k in entities if k.endswith("/violating_trace")]:
        view = k.rsplit("/", 1)[0]
        siblings = sorted(e for e in entities if e.startswith(view + "/")
                          and e.count("/") >= k.count("/") and not e.endswith("/zero"))
        assert siblings[-1] == k, (k, siblings[-1])
    margin = entities["/scalars/unsafe_distance/violating_trace"]
    m = margin.values("Scalars:scalars")
    t = margin.time
    assert m[0] > 0 and np.min(m) <= 0  # starts outside, enters the unsafe box
    assert t[np.argmax(m <= 0)] == ns(cex.t)  # first at the counterexample's time
    text = entities["/verdict"].per_row("TextDocument:text")[0][0]
    assert "UNSAFE" in text and "counterexample" in text and "enters unsafe set 0" in text
    assert summary.boxes == result.tube.num_boxes
    # the unsafe box is filled in the overlay (class 1 or 3 where the tube meets it)
    image, labels, scale, shift = segmentation(entities, "/plane/overlay")
    assert labels[1] == "unsafe set" and labels[2] == "reachtube"
    rows, cols = np.nonzero(np.isin(image, (1, 3)))
    xy = shift[:2] + (np.column_stack([cols, rows]) + 0.5) * scale[:2]
    assert rows.size and np.all(np.abs(xy) <= 1.0 + 1e-9)  # the box [-1, 1]^2
    assert "counterexample magenta" in " ".join(view_kinds(summary.path))


def test_without_result(di, tmp_path):
    problem, law, _ = di
    summary = write_recording(tmp_path / "law.rrd", problem, law)
    entities = read(summary.path)
    assert summary.boxes == 0 and summary.traces == 16
    assert "/plane/regions" in entities and "/plane/initial" in entities
    assert not any("/tube" in k for k in entities)
    assert "not verified" in entities["/verdict"].per_row("TextDocument:text")[0][0]
    check_recording(summary.path)


def test_without_verify_section(tmp_path):
    problem = ce.loads_spec(DI_TEXT.split("[verify]")[0])
    assert problem.verify is None
    law = ce.synthesize(problem)
    summary = write_recording(tmp_path / "bare.rrd", problem, law)
    assert {k for k, v in summary.entities.items() if v} == {
        "/plane/regions",
        "/plane/edges",
        "/plane/axes/frame",
        "/plane/axes/ticks",
        "/plane/axes/x_labels",
        "/plane/axes/y_labels",
        "/verdict",
    }
    assert summary.traces == 0
    check_recording(summary.path)


def test_one_state(tmp_path):
    problem = ce.load_spec(EXAMPLES / "cruise_control.toml")
    law = ce.synthesize(problem)
    # axes are ignored for n == 1: the plane is (time, v)
    opts = RecordingOptions(axes=(0, 5), traces=3)
    summary = write_recording(tmp_path / "cc.rrd", problem, law, None, options=opts)
    entities = read(summary.path)
    image, labels, scale, shift = segmentation(entities, "/plane/regions")
    assert summary.entities["/plane/regions"] == law.num_regions
    for k in ("/plane/initial", "/plane/unsafe/0", "/plane/unsafe/1", "/plane/traces"):
        assert k in entities, k
    assert "/time/v/traces/2" in entities
    ticks = entities["/plane/axes/ticks"].per_row("Points2D:labels")[0]
    assert "time →" in ticks and "v ↑" in ticks
    assert summary.traces == 3


# ---------------------------------------------------------------------------------------
# file checks and atomicity
# ---------------------------------------------------------------------------------------


def test_check_recording(di_recording, tmp_path):
    summary, _ = di_recording
    check_recording(summary.path)
    data = summary.path.read_bytes()
    half = tmp_path / "half.rrd"
    half.write_bytes(data[: len(data) // 2])
    with pytest.raises(ce.SpecError, match="incomplete|truncated") as err:
        check_recording(half)
    assert err.value.file == str(half)
    with pytest.raises(ce.SpecError, match="not found"):
        check_recording(tmp_path / "missing.rrd")
    with pytest.raises(ce.SpecError, match="not a file"):
        check_recording(tmp_path)
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(ce.SpecError, match=r"\.rrd"):
        check_recording(text)
    fake = tmp_path / "fake.rrd"
    fake.write_bytes(b"not a recording at all")
    with pytest.raises(ce.SpecError, match="not a Rerun recording"):
        check_recording(fake)
    empty = tmp_path / "empty.rrd"
    empty.write_bytes(b"")
    with pytest.raises(ce.SpecError):
        check_recording(empty)


@pytest.mark.parametrize("axes", [(0, 0), (0, 2), (-1, 1), (0,), (0.0, 1)])
def test_bad_axes(di, tmp_path, axes):
    problem, law, result = di
    path = tmp_path / "bad.rrd"
    with pytest.raises(ce.SpecError) as err:
        write_recording(path, problem, law, result, options=RecordingOptions(axes=axes))
    assert err.value.field == "axes"
    assert not path.exists() and no_leftovers(tmp_path)


def test_bad_arguments(di, tmp_path):
    problem, law, result = di
    with pytest.raises(ce.SpecError) as err:
        write_recording(tmp_path / "x.rrd", problem, law, options=RecordingOptions(traces=-1))
    assert err.value.field == "traces"
    with pytest.raises(ce.SpecError, match=r"\.rrd"):
        write_recording(tmp_path / "x.txt", problem, law)
    other = ce.load_spec(EXAMPLES / "cruise_control.toml")
    with pytest.raises(ce.SpecError, match="n=2"):
        write_recording(tmp_path / "x.rrd", other, law)
    assert list(tmp_path.iterdir()) == []


def test_failure_midway_leaves_nothing(di, tmp_path, monkeypatch):
    problem, law, result = di
    path = tmp_path / "out.rrd"
    write_recording(path, problem, law, result, options=RecordingOptions(traces=2))
    old = path.read_bytes()
    calls = []

    def boom(writer, content):
        calls.append(dict(writer.entities))
        raise RuntimeError("boom")

    monkeypatch.setattr(records, "_send_blueprint", boom)
    with pytest.raises(RuntimeError, match="boom"):
        write_recording(path, problem, law, result, options=RecordingOptions(traces=2))
    assert calls and "/plane/tube" in calls[0]  # it failed after logging the data
    assert path.read_bytes() == old  # the previous recording is untouched
    assert no_leftovers(tmp_path)
    fresh = tmp_path / "fresh.rrd"
    with pytest.raises(RuntimeError, match="boom"):
        write_recording(fresh, problem, law, result, options=RecordingOptions(traces=2))
    assert not fresh.exists() and no_leftovers(tmp_path)
    assert sorted(os.listdir(tmp_path)) == ["out.rrd"]


def test_rerun_disabled(di, tmp_path, monkeypatch):
    problem, law, result = di
    monkeypatch.setenv("RERUN", "off")
    with pytest.raises(ce.CodevError, match="RERUN=off"):
        write_recording(tmp_path / "off.rrd", problem, law, result)
    assert list(tmp_path.iterdir()) == []


def test_many_boxes(di, tmp_path):
    """1e4 tube boxes (the time is in docs/recordings.md; no timed assertion here)."""
    problem, law, _ = di
    K = 10_000
    rng = np.random.default_rng(3)
    t_start = np.repeat(np.arange(2_000) * 0.0045, 5)
    lower = rng.uniform(-5.0, 5.0, (K, 2))
    tube = Tube(t_start, t_start + 0.0045, lower, lower + 0.1, np.zeros(K, dtype=int))
    result = VerificationResult("robustly_safe", None, tube, "continuous")
    summary = write_recording(
        tmp_path / "big.rrd", problem, law, result, options=RecordingOptions(traces=0)
    )
    assert summary.boxes == K and summary.entities["/plane/tube"] == K
    entities = read(summary.path)
    assert entities["/plane/tube"].instances("Boxes2D:half_sizes") == K
    assert entities["/time/x1/tube/upper"].instances("Scalars:scalars") > 0
    assert len(np.unique(entities["/plane/tube"].time)) == 2_000


# ---------------------------------------------------------------------------------------
# the unsafe margin
# ---------------------------------------------------------------------------------------


def test_unsafe_margin():
    box = SetSpec("box", lower=np.array([0.0, 0.0]), upper=np.array([1.0, np.inf]))
    X = np.array([[0.5, 5.0], [3.0, 0.5], [-0.25, 10.0], [0.5, -2.0]])
    assert np.allclose(unsafe_margin([box], X), [-0.5, 2.0, 0.25, 2.0])
    # a polytope with rows of any norm: normalised, x1 + x2 <= 1 scaled by 10
    half = SetSpec("polytope", A=np.array([[10.0, 10.0]]), b=np.array([10.0]))
    assert np.allclose(unsafe_margin([half], np.array([[1.0, 1.0]])), [1.0 / np.sqrt(2)])
    both = unsafe_margin([box, half], X)
    assert np.allclose(both, np.minimum(unsafe_margin([box], X), unsafe_margin([half], X)))
    assert np.all(unsafe_margin([], X) == np.inf)


# ---------------------------------------------------------------------------------------
# rasters and the tube's hull (what the plane and the state views are drawn from)
# ---------------------------------------------------------------------------------------


def test_raster_polygons_pixel_centres():
    from codev_engine.view.shapes import raster_polygons

    tri = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])  # counter-clockwise
    sq = np.array([[3.0, 3.0], [3.0, 4.0], [4.0, 4.0], [4.0, 3.0]])  # clockwise
    lo, hi = np.array([0.0, 0.0]), np.array([4.0, 4.0])
    img = raster_polygons([tri, sq], lo, hi, (40, 40), np.array([7, 9]))
    assert img.dtype == np.uint32 and img.shape == (40, 40)
    r, c = np.mgrid[0:40, 0:40]
    x, y = (c + 0.5) * 0.1, (r + 0.5) * 0.1  # row 0 at the bottom
    assert np.array_equal(img == 7, (x + y <= 4.0) & ~((x >= 3) & (y >= 3)))
    assert np.array_equal(img == 9, (x >= 3) & (y >= 3))  # later polygons on top
    # outside the window: nothing; a flat polygon: nothing
    far = raster_polygons([tri + 10.0, tri[:2]], lo, hi, (8, 8))
    assert not far.any()


def test_raster_boxes_union_and_least_width():
    from codev_engine.view.shapes import raster_boxes

    lo, hi = np.array([0.0, 0.0]), np.array([10.0, 10.0])
    lower = np.array([[1.0, 1.0], [2.0, 2.0], [5.0, 5.0]])
    upper = np.array([[3.0, 3.0], [4.0, 4.0], [5.0001, 9.0]])  # the last: thinner than a pixel
    m = raster_boxes(lower, upper, lo, hi, (10, 10), min_pixels=2)
    want = np.zeros((10, 10), dtype=bool)
    want[1:3, 1:3] = want[2:4, 2:4] = True
    assert np.array_equal(m[:, :4], want[:, :4]) and not m[:5, 4:].any() and not m[9:].any()
    thin = m[5:9, 4:]  # widened about x = 5 to 2 pixels (3 when it straddles pixel edges)
    assert thin[:, :2].all() and 2 <= thin.sum(axis=1).min() <= thin.sum(axis=1).max() <= 3
    assert not raster_boxes(np.zeros((0, 2)), np.zeros((0, 2)), lo, hi, (4, 4)).any()


def test_tube_envelope_contains_every_box():
    from codev_engine.view.record_content import tube_envelope

    ts = np.array([0.0, 0.0, 1.0, 2.5])
    te = np.array([1.0, 2.0, 2.0, 3.0])  # [2, 2.5] uncovered
    lo = np.array([[0.0], [-1.0], [0.5], [3.0]])
    hi = np.array([[1.0], [0.5], [2.0], [4.0]])
    t, elo, ehi = tube_envelope(ts, te, lo, hi)
    assert np.array_equal(t, [0.0, 1.0, 2.0, 2.5, 3.0])
    assert np.array_equal(elo[:, 0], [-1.0, -1.0, np.nan, 3.0], equal_nan=True)
    assert np.array_equal(ehi[:, 0], [1.0, 2.0, np.nan, 4.0], equal_nan=True)
    rng = np.random.default_rng(1)
    K = 500
    ts = np.round(rng.uniform(0, 5, K), 2)
    te = ts + np.round(rng.uniform(0.01, 1, K), 2)
    lo = rng.normal(size=(K, 3))
    hi = lo + rng.uniform(0, 1, (K, 3))
    t, elo, ehi = tube_envelope(ts, te, lo, hi)
    for k in range(K):
        seg = (t[:-1] >= ts[k]) & (t[1:] <= te[k])
        assert seg.any()
        assert np.all(elo[seg] <= lo[k]) and np.all(ehi[seg] >= hi[k])


# ---------------------------------------------------------------------------------------
# references and outputs (issue 25): the servo tracking a reference box, soft output bounds
# ---------------------------------------------------------------------------------------

SERVO_TEXT = (EXAMPLES / "dc_motor_servo.toml").read_text().replace(
    "time_horizon = 2.0", "time_horizon = 0.2"  # a short verification: 0.1 s CPU
)
SOFT_TEXT = (EXAMPLES / "mass_spring_soft.toml").read_text().replace(
    "time_horizon = 8.0", "time_horizon = 2.0"
)


def _written(text: str, folder: Path, traces: int = 4):
    problem = ce.loads_spec(text)
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    path = folder / "design.rrd"
    summary = write_recording(path, problem, law, result, options=RecordingOptions(traces=traces))
    return problem, result, summary, read(path)


@pytest.fixture(scope="module")
def servo_recording(tmp_path_factory):
    return _written(SERVO_TEXT, tmp_path_factory.mktemp("servo"))


@pytest.fixture(scope="module")
def soft_recording(tmp_path_factory):
    return _written(SOFT_TEXT, tmp_path_factory.mktemp("soft"))


def _series(e: Entity) -> tuple[np.ndarray, np.ndarray]:
    return e.time / 1e9, e.values("Scalars:scalars")


def _hull_contains_output_boxes(entities, name: str, C: np.ndarray, tube) -> None:
    """The logged hull of y = C x contains C applied to every tube box (checked at each
    box's mid-time, float32 file)."""
    t, lo = _series(entities[f"/output/{name}/tube/lower"])
    _, hi = _series(entities[f"/output/{name}/tube/upper"])
    assert len(t) > 0 and np.all(np.diff(t) >= 0)
    k = int(name[1:])
    c = 0.5 * (tube.lower + tube.upper) @ C[k]
    r = 0.5 * (tube.upper - tube.lower) @ np.abs(C[k])
    mid = 0.5 * (tube.t_start + tube.t_end)
    j = np.searchsorted(t, mid)
    assert np.all(lo[j] <= c - r + 1e-5) and np.all(hi[j] >= c + r - 1e-5)
    # and it is tight: some box touches each side
    assert np.min(c - r - lo[j]) < 1e-5 and np.min(hi[j] - c - r) < 1e-5


def test_servo_recording_draws_the_reference_box_on_the_output(servo_recording):
    problem, result, summary, entities = servo_recording
    horizon = problem.verify.time_horizon
    for side, value in (("lower", 0.45), ("upper", 0.55)):  # [verify] reference
        t, v = _series(entities[f"/output/y0/reference/{side}"])
        assert t == pytest.approx([0.0, horizon]) and v == pytest.approx([value] * 2)
        assert entities[f"/output/y0/reference/{side}"].per_row("SeriesLines:names") == [
            [f"reference {side}"]
        ]
    # no reference on the states (it follows y), no bounds on y (none in the spec)
    assert not any("/reference/" in k for k in entities if k.startswith("/time/"))
    assert not any(k.startswith("/output/y0/bounds/") for k in entities)
    C = np.asarray(problem.mpc.C)
    _hull_contains_output_boxes(entities, "y0", C, result.tube)
    # each trace's output is C x of its states
    for p in range(4):
        t, y = _series(entities[f"/output/y0/traces/{p}"])
        t2, x = _series(entities[f"/time/angle/traces/{p}"])
        assert np.array_equal(t, t2) and np.allclose(y, x, atol=1e-6) and len(y) > 10
    assert summary.entities["/output/y0/reference/lower"] == 2
    kinds = view_kinds(summary.path)
    outs = [n for n in kinds if n.startswith("y0(t) = C x")]
    assert len(outs) == 1 and kinds[outs[0]] == "TimeSeries" and "reference purple" in outs[0]


def test_soft_output_bound_and_the_outputs_tube(soft_recording):
    problem, result, summary, entities = soft_recording
    t, v = _series(entities["/output/y0/bounds/max"])
    assert t == pytest.approx([0.0, problem.verify.time_horizon]) and v == pytest.approx([1.0, 1.0])
    assert entities["/output/y0/bounds/max"].per_row("SeriesLines:names") == [["y_max (soft)"]]
    assert "/output/y0/bounds/min" not in entities  # no y_min in the spec
    assert not any("/reference/" in k for k in entities)  # it regulates
    _hull_contains_output_boxes(entities, "y0", np.asarray(problem.mpc.C), result.tube)
    kinds = view_kinds(summary.path)
    assert any(n.startswith("y0(t) = C x") and "bounds black" in n for n in kinds)


def test_a_fixed_state_reference_is_drawn_on_the_states(tmp_path):
    """signal = "x": the value on each state's series; no output view without C."""
    text = SERVO_TEXT.split("[mpc.reference]")[0].replace('C = [[1.0, 0.0]]', "")
    text += '[mpc.reference]\nsignal = "x"\nvalue = [0.5, 0.0]\n' + (
        "[verify]" + SERVO_TEXT.split("[verify]")[1]
    ).replace("reference = { lower = [0.45], upper = [0.55] }", "")
    problem = ce.loads_spec(text)
    law = ce.synthesize(problem)
    summary = write_recording(tmp_path / "x.rrd", problem, law,
                              options=RecordingOptions(traces=2))
    entities = read(summary.path)
    for s, value in (("angle", 0.5), ("speed", 0.0)):
        t, v = _series(entities[f"/time/{s}/reference/value"])
        assert v == pytest.approx([value] * 2) and t == pytest.approx([0.0, 0.2])
    assert not any(k.startswith("/output/") for k in entities)


def test_output_boxes_contain_every_output():
    from codev_engine.view.signals import output_boxes

    rng = np.random.default_rng(3)
    C = rng.normal(size=(3, 4)) * 10.0 ** rng.integers(-3, 3, size=(3, 4))
    lo = rng.normal(size=(50, 4)) * 1e3
    hi = lo + rng.uniform(0, 1e-3, size=(50, 4)) * np.abs(lo)
    ylo, yhi = output_boxes(C, lo, hi)
    X = rng.uniform(lo[:, None, :], hi[:, None, :], size=(50, 200, 4))
    corners = np.where((np.arange(16)[:, None] >> np.arange(4)) & 1, hi[:, None, :], lo[:, None, :])
    for P in (X, corners):
        Y = np.einsum("kpn,qn->kpq", P, C)
        assert np.all(Y >= ylo[:, None, :]) and np.all(Y <= yhi[:, None, :])


def test_counterexample_output_is_c_of_its_states(tmp_path):
    """An unsafe soft design: the counterexample's output y0 = p is logged on the output
    view, equal to its state series."""
    text = SOFT_TEXT.replace("lower = [1.3, -inf]", "lower = [0.75, -inf]")
    problem, result, summary, entities = _written(text, tmp_path, traces=0)
    assert result.verdict == "unsafe" and result.counterexample is not None
    t, y = _series(entities["/output/y0/violating_trace"])
    t2, x = _series(entities["/time/p/violating_trace"])
    assert len(y) > 2 and np.array_equal(t, t2) and np.allclose(y, x, atol=1e-6)
    assert any(n.startswith("y0(t) = C x") and "counterexample magenta" in n
               for n in view_kinds(summary.path))


def test_all_time_recording_draws_the_certificate_band_to_the_view_s_end(tmp_path):
    # cruise_grade ("inf"): the tube's series stop at the closing sample (3 s), the band's
    # run from there to the shown horizon (25 s); the verdict names the set of the width
    from codev_engine.reach.claim import certificate_band

    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    write_recording(tmp_path / "cg.rrd", problem, law, result,
                    options=RecordingOptions(traces=2))
    entities = read(tmp_path / "cg.rrd")
    band = certificate_band(result)
    lo, hi = entities["/time/v/certificate/lower"], entities["/time/v/certificate/upper"]
    assert np.allclose(lo.time / 1e9, [band.t_closed, 25.0]) and np.allclose(hi.time, lo.time)
    assert np.allclose(lo.values("Scalars:scalars"), band.lower[0], atol=1e-5)
    assert np.allclose(hi.values("Scalars:scalars"), band.upper[0], atol=1e-5)
    assert entities["/time/v/tube/lower"].time.max() / 1e9 == pytest.approx(band.t_closed)
    text = entities["/verdict"].per_row("TextDocument:text")[0][0]
    assert "| width at t = 25 s (certificate band) |" in text
    assert "**time**: for all t >= 0 (invariance certificate" in text
    assert any("certificate band purple" in n for n in view_names(tmp_path / "cg.rrd"))


def test_recording_and_report_name_the_same_section(magnetic, tmp_path):
    # one rule (scene.default_slice_point with the spec): the plane view's title, the
    # report's partition caption and its figure title say the same "section at x3 = ..."
    from codev_engine.view.report import report_html

    problem, law = magnetic
    summary = write_recording(tmp_path / "s.rrd", problem, law, None,
                              options=RecordingOptions(traces=0))
    x3 = 0.5 * (problem.verify.initial_lower[2] + problem.verify.initial_upper[2])
    words = f"section at x3 = {x3:.3g}"
    (plane,) = [n for n in view_names(summary.path) if n.startswith("plane")]
    assert words in plane
    text = report_html(problem, law, None, traces=0)
    assert f"The partition of the explicit law: {words}: " in text
    assert text.count(words) >= 3  # the caption, the figure's own title, the first screen
    # the first screen (above the figures) says it, as the recording's plane title does
    assert f"The partition (Figure 1) is the {words}." in text[: text.index("<figure")]


def test_one_state_initial_set_is_drawn_at_t0_only(tmp_path):
    # n == 1: the plane is (t, v); the initial set holds at t = 0, not across the horizon
    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    law = ce.synthesize(problem)
    summary = write_recording(tmp_path / "i.rrd", problem, law, None,
                              options=RecordingOptions(traces=0))
    strip = np.array(read(summary.path)["/plane/initial"].per_row("LineStrips2D:strips")[0][0])
    assert strip[:, 0].min() <= 0.0 and 0.0 < strip[:, 0].max() <= 0.02 * 25.0 + 1e-6
    assert np.allclose([strip[:, 1].min(), strip[:, 1].max()], [8.0, 9.0], atol=1e-5)


def test_each_state_view_draws_its_unsafe_limits(tmp_path):
    # cruise_grade: v >= 11 and v <= 7 are unsafe; the v(t) view draws 11 and 7 (red)
    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    law = ce.synthesize(problem)
    summary = write_recording(tmp_path / "l.rrd", problem, law, None,
                              options=RecordingOptions(traces=0))
    e = read(summary.path)
    assert np.allclose(e["/time/v/unsafe/0/lower"].values("Scalars:scalars"), 11.0)
    assert np.allclose(e["/time/v/unsafe/1/upper"].values("Scalars:scalars"), 7.0)
    assert "/time/v/unsafe/0/upper" not in e  # an infinite side is not drawn
    assert any("unsafe limits red" in n for n in view_names(summary.path))
