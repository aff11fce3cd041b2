"""Held-out spec fuzzer (not run by the suite): N mutated specs, big and deep mutations, from a
seed, each through ``codev run`` in a real process with a timeout, tabulated by outcome.

    .venv/bin/python tests/fuzz/heldout.py --seed 4711 [--count 200] [--timeout 60]
        [--jobs 1] [--out DIR]

Outcome classes (tests/fuzz/contract.py): verdict / exit2_one_line / exit1_one_line (the
contract) and internal_error / traceback / warning_spill / hang / injection / bad_error_line /
other_status (failures). Every failing spec is kept in DIR (default ./fuzz-heldout-SEED) with
its stderr, and the distinct failures (class + message with numbers masked) are listed with
the smallest spec that triggers each.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from hypothesis import strategies as st  # noqa: E402

from tests.fuzz.contract import CLASSES, GOOD, classify, run_subprocess  # noqa: E402
from tests.fuzz.mutations import (  # noqa: E402
    ALL,
    fill_canary,
    hostile_values,
    load_example,
    mutate,
    spec_text,
)


def make_specs(seed: int, count: int) -> list[tuple[str, str]]:
    """``count`` mutated specs: Hypothesis generating from ``seed`` (no shrinking, no
    database), each a bundled example with 1-5 mutations."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import seed as hseed

    out: list[tuple[str, str]] = []

    @hseed(seed)
    @settings(max_examples=count, phases=[Phase.generate], database=None, deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def gen(data):
        base = data.draw(st.sampled_from(ALL), label="example")
        k = data.draw(st.sampled_from([1, 1, 2, 3, 5]), label="k")
        doc = mutate(load_example(base), data, values=hostile_values(), k=k)
        out.append((f"{len(out):03d}-{base}", spec_text(doc)))

    gen()
    return out[:count]


def _mask(msg: str) -> str:
    msg = re.sub(r"/tmp/\S+?/spec\.toml", "SPEC", msg)
    msg = re.sub(r"\d+(\.\d+)?(e[-+]?\d+)?", "N", msg)
    return msg[:200]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--count", type=int, default=200)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--time-limit", type=float, default=None,
                    help="pass codev's --time-limit (a run past it ends in one line, exit 1)")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    out = args.out or Path(f"fuzz-heldout-{args.seed}")
    out.mkdir(parents=True, exist_ok=True)
    specs = make_specs(args.seed, args.count)

    def one(item):
        name, text = item
        with tempfile.TemporaryDirectory(prefix="codev-heldout-") as tmp:
            tmp = Path(tmp)
            canary = tmp / "CANARY-executed"
            spec = tmp / "spec.toml"
            spec.write_text(fill_canary(text, canary), encoding="utf-8")
            argv = ["run", "-q", str(spec)]
            if args.time_limit:
                argv[2:2] = ["--time-limit", f"{args.time_limit:g}"]
            o = run_subprocess(argv, cwd=tmp, timeout=args.timeout)
            cls = classify(o, names=(str(spec),), canaries=(canary,))
        return name, text, o, cls

    rows = []
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        for name, text, o, cls in pool.map(one, specs):
            tail = (o.stderr.strip().splitlines() or [""])[-1]
            rows.append({"spec": name, "class": cls, "status": o.status,
                         "seconds": round(o.seconds, 2), "stderr_last": tail[:500]})
            print(f"{name}: {cls} ({o.seconds:.1f} s) {tail[:160]}", flush=True)
            if cls not in GOOD:
                (out / f"{name}.toml").write_text(text, encoding="utf-8")
                (out / f"{name}.stderr").write_text(o.stderr, encoding="utf-8")
    counts = {c: sum(r["class"] == c for r in rows) for c in CLASSES}
    distinct: dict[tuple[str, str], dict] = {}
    for r, (_, text) in zip(rows, specs, strict=True):
        if r["class"] in GOOD:
            continue
        key = (r["class"], _mask(r["stderr_last"]))
        if key not in distinct or len(text) < distinct[key]["size"]:
            distinct[key] = {"class": r["class"], "message": r["stderr_last"][:300],
                             "spec": r["spec"], "size": len(text), "count": 0}
        distinct[key]["count"] = distinct[key].get("count", 0) + 1
    (out / "summary.json").write_text(json.dumps(
        {"seed": args.seed, "count": args.count, "timeout": args.timeout, "counts": counts,
         "distinct": list(distinct.values()), "rows": rows}, indent=1))
    print("\n| outcome | specs |\n|---|---|")
    for c in CLASSES:
        print(f"| {c} | {counts[c]} |")
    print("\ndistinct failures:")
    for d in distinct.values():
        print(f"- [{d['class']}] x{d['count']} {d['spec']}: {d['message'][:200]}")
    return 0 if all(counts[c] == 0 for c in CLASSES if c not in GOOD) else 1


if __name__ == "__main__":
    sys.exit(main())
