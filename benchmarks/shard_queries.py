"""Benchmark: the shards a box question reads on a sharded law, with and without the
manifest's group boxes, and with its halo (issue 43).

Usage::

    python benchmarks/shard_queries.py LAW_DIR [--queries 300] [--widths 0.01,0.05]

``LAW_DIR`` is a sharded law (``benchmarks/scale.py --sharded --out-shards DIR``, then
``DIR/<workers>``). The query boxes are cubes of ``width`` times the widest side of the
law's shard boxes, centred at the Chebyshev centres of regions drawn at random (points of
the domain). For each width, once with the manifest as written (its shards' group boxes,
``law_shard_writer.box_groups``) and once with the same shard files under a manifest without
the groups (as one written before them: each shard's box alone; a folder of links in a
temporary folder), it reports per query:

- the shards ``regions_meeting`` and ``domain_rows`` look in (``ShardedLaw.met``), and
  the shards holding a region whose bounding box meets the box (the least any summary of
  the boxes can read);
- the time of ``regions_meeting`` + ``domain_rows`` on a fresh ``ShardedLaw`` (cold: the
  shards read from disk and checked) and on one holding every shard (warm).

With a halo (``law_halo``: the law of the sharded search has one; ``--add-halo`` builds one
for a law written before, in a copy of its folder, timing the CPU it takes here), a third
run reads the law as written (a box question reads the shards and halos of the cells it
meets) and the first two the same files under a manifest without the halo. It also
reports the files read per query (``ShardedLaw.loads``, cold: shards and halos) and the
halo's storage. The answers must all be equal (it prints ``DIFFER`` if not). The load
average is printed before and after. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


#: a halo's fields in a manifest entry
HALO_KEYS = ("halo_file", "halo_sha256", "halo_bytes", "halo", "halo_facets")


def _without(folder: Path, into: Path, keys: tuple[str, ...]) -> Path:
    """The law of ``folder`` under a manifest without ``keys`` in its entries (links to
    its files)."""
    from codev_engine.law_shards import MANIFEST

    into.mkdir()
    for f in folder.iterdir():
        if f.name != MANIFEST:
            (into / f.name).symlink_to(f.resolve())
    data = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
    for e in data["shards"]:
        for key in keys:
            e.pop(key, None)
    (into / MANIFEST).write_text(json.dumps(data), encoding="utf-8")
    return into


def _add_halo(folder: Path, into: Path) -> tuple[Path, float]:
    """A copy of ``folder`` with a halo built here (its manifest's cells); the CPU seconds."""
    from codev_engine.law_halo import build_halo
    from codev_engine.law_shards import MANIFEST

    shutil.copytree(folder, into)
    data = json.loads((into / MANIFEST).read_text(encoding="utf-8"))
    t0 = time.process_time()
    data["shards"] = build_halo(into, data["shards"], int(data["n"]), int(data["m"]))
    cpu = time.process_time() - t0
    (into / MANIFEST).write_text(json.dumps(data), encoding="utf-8")
    return into, cpu


def _queries(law, k: int, seed: int = 0) -> np.ndarray:
    """Chebyshev centres of ``k`` regions drawn at random: (k, n)."""
    from codev_engine.geometry.polytope import chebyshev_ball

    rng = np.random.default_rng(seed)
    pick = rng.integers(0, law.num_regions, size=k)
    return np.array([chebyshev_ball(law.A[int(i)], law.b[int(i)])[0] for i in pick])


def _run(folder: Path, C: np.ndarray, r: float, cold: int) -> dict:
    from codev_engine.law_shards import ShardedLaw

    warm = ShardedLaw(folder, cache=10**6)
    answers, t = [], []
    for x in C:
        t0 = time.perf_counter()
        got = warm.regions_meeting(x - r, x + r)
        warm.domain_rows(x - r, x + r)
        t.append(time.perf_counter() - t0)
        answers.append(got)
    met = warm.met / (2 * len(C))  # (each query asks both)
    t_cold, loads = [], []
    for x in C[:cold]:
        t0 = time.perf_counter()
        fresh = ShardedLaw(folder, cache=10**6)
        fresh.regions_meeting(x - r, x + r)
        fresh.domain_rows(x - r, x + r)
        t_cold.append(time.perf_counter() - t0)
        loads.append(fresh.loads)
    return {"shards_per_query": met, "warm_ms": 1e3 * float(np.median(t[1:] or t)),
            "cold_ms": 1e3 * float(np.median(t_cold)), "answers": answers,
            "files": float(np.mean(loads))}


def main(argv: list[str] | None = None) -> int:
    from codev_engine.law_shards import ShardedLaw

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("law", help="a sharded law's folder")
    ap.add_argument("--queries", type=int, default=300)
    ap.add_argument("--cold", type=int, default=20, help="queries timed cold (default 20)")
    ap.add_argument("--widths", default="0.01,0.05",
                    help="query widths, fractions of the law's box (default 0.01,0.05)")
    ap.add_argument("--add-halo", action="store_true",
                    help="build a halo for a law without one (in a copy of its folder)")
    args = ap.parse_args(argv)
    print(f"load average before: {os.getloadavg()}")
    folder = Path(args.law)
    built = tempfile.TemporaryDirectory()
    if args.add_halo:
        folder, cpu = _add_halo(folder, Path(built.name) / "halo")
        print(f"halo built here: {cpu:.1f} s CPU (load {os.getloadavg()[0]:.1f})")
    law = ShardedLaw(folder, cache=10**6)
    if law.has_halo:
        own = sum(f.stat().st_size for f in folder.glob("shard-*.npz"))
        halo = sum(f.stat().st_size for f in folder.glob("halo-*.npz"))
        copies = sum(int(e["halo"]) for e in law._entries)
        print(f"halo: {copies} copies of {law.num_regions} regions ("
              f"{copies / max(1, law.num_regions):.2f} per region), {halo / 1e6:.1f} MB "
              f"beside the shards' {own / 1e6:.1f} MB (x{(own + halo) / max(1, own):.2f}), "
              f"{sum(int(e['halo_facets']) for e in law._entries)} facets")
    lo = np.min([g.min(axis=0) for g in law._lo if g.shape[0]], axis=0)
    hi = np.max([g.max(axis=0) for g in law._hi if g.shape[0]], axis=0)
    width = float(np.max(hi - lo))
    C = _queries(law, args.queries)
    boxes = [law.shard(j).boxes for j in range(law.shards)]
    print(f"{law!r}: {sum(g.shape[0] for g in law._lo)} group boxes, manifest "
          f"{(folder / 'shards.json').stat().st_size / 1e3:.0f} kB; {len(C)} queries, "
          f"the law's box {width:.3g} wide")
    with tempfile.TemporaryDirectory() as tmp:
        stripped = _without(folder, Path(tmp) / "nohalo", HALO_KEYS)
        before = _without(stripped, Path(tmp) / "law", ("groups_lo", "groups_hi"))
        for frac in (float(w) for w in args.widths.split(",")):
            r = 0.5 * frac * width
            least = np.mean([sum(bool(np.any(np.all(blo <= x + r + 1e-9, axis=1)
                                             & np.all(bhi >= x - r - 1e-9, axis=1)))
                                 for blo, bhi in boxes) for x in C])
            old, new = _run(before, C, r, args.cold), _run(stripped, C, r, args.cold)
            same = all(np.array_equal(a, b) for a, b in zip(old["answers"], new["answers"],
                                                            strict=True))
            if law.has_halo:
                cells = np.mean([len(law._cells_meeting(x - r, x + r)) for x in C])
                got = _run(folder, C, r, args.cold)
                same &= all(np.array_equal(a, b) for a, b in zip(old["answers"],
                                                                 got["answers"], strict=True))
            print(f"width {frac:g}: shards read per query {old['shards_per_query']:.2f} "
                  f"(shard boxes) -> {new['shards_per_query']:.2f} (group boxes), at least "
                  f"{least:.2f} (the region boxes); per query warm {old['warm_ms']:.2f} -> "
                  f"{new['warm_ms']:.2f} ms, cold {old['cold_ms']:.0f} -> "
                  f"{new['cold_ms']:.0f} ms; answers {'equal' if same else 'DIFFER'}",
                  flush=True)
            if law.has_halo:
                print(f"width {frac:g}, halo: shards read per query {got['shards_per_query']:.2f}"
                      f" (cells met {cells:.2f}), files read cold {new['files']:.2f} -> "
                      f"{got['files']:.2f}; per query warm {new['warm_ms']:.2f} -> "
                      f"{got['warm_ms']:.2f} ms, cold {new['cold_ms']:.0f} -> "
                      f"{got['cold_ms']:.0f} ms", flush=True)
    print(f"load average after: {os.getloadavg()}")
    built.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
