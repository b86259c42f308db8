"""Every JSON number of two ``jaxflex reproduce`` output directories, old against new.

    python tests/scripts/compare_results.py OLD_DIR NEW_DIR [--rtol 1e-12]

Walks every ``*.json`` file of OLD_DIR, pairs it with NEW_DIR's, and compares every number (relative
difference |a - b| / max(|a|, |b|); exact for integers and strings). Wall-clock fields (times,
dates, versions of the run) are listed apart, not compared. Prints the number of values compared,
the largest relative differences and every value beyond ``rtol``; exits 1 if any value differs
beyond it or the structures differ.
"""
import argparse
import json
import math
import pathlib
import sys

# keys whose values measure the run, not the physics: wall and CPU times, dates, host facts
TIMING = ("_s", "_s_", "time", "times", "created", "wall", "elapsed", "seconds", "python", "jax_version",
          "jaxflex_version", "hostname", "platform", "devices", "peak_rss", "eta", "step_times_s", "git")


def _is_timing(path: str) -> bool:
    last = path.rsplit("/", 1)[-1]
    return (any(last.endswith(t) or last == t for t in TIMING) or "provenance" in path or "timing" in path
            or last in ("out", "argv", "cwd"))


def walk(a, b, path, out):
    if _is_timing(path):
        out["timing"].append(path)
        return
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            out["structure"].append(f"{path}: keys {sorted(set(a) ^ set(b))}")
        for k in sorted(set(a) & set(b)):
            walk(a[k], b[k], f"{path}/{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out["structure"].append(f"{path}: lengths {len(a)} != {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            walk(x, y, f"{path}[{i}]", out)
    elif isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or isinstance(b, str) or a is None or b is None:
        out["count"] += 1
        if a != b:
            out["exact"].append(f"{path}: {a!r} != {b!r}")
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)):
        out["count"] += 1
        if a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)):
            d = 0.0
        else:
            d = abs(a - b) / max(abs(a), abs(b))
        out["diffs"].append((d, path, a, b))
    else:
        out["structure"].append(f"{path}: types {type(a).__name__} != {type(b).__name__}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("old")
    p.add_argument("new")
    p.add_argument("--rtol", type=float, default=1e-12)
    args = p.parse_args(argv)
    old, new = pathlib.Path(args.old), pathlib.Path(args.new)
    out = {"count": 0, "diffs": [], "exact": [], "structure": [], "timing": []}
    files = sorted(f.relative_to(old) for f in old.rglob("*.json"))
    missing = [str(f) for f in files if not (new / f).exists()]
    for f in files:
        if (new / f).exists():
            walk(json.loads((old / f).read_text()), json.loads((new / f).read_text()), str(f), out)
    worst = sorted(out["diffs"], reverse=True)
    bad = [w for w in worst if w[0] > args.rtol]
    print(f"{len(files)} JSON files, {out['count']} values compared ({len(out['diffs'])} numbers), "
          f"{len(out['timing'])} wall-clock fields skipped")
    print("largest relative differences:")
    for d, path, a, b in worst[:8]:
        print(f"  {d:.3e}  {path}  ({a!r} / {b!r})")
    for what in ("structure", "exact"):
        if out[what]:
            print(f"{what} differences ({len(out[what])}):")
            for line in out[what][:20]:
                print("  " + line)
    if missing:
        print("missing in new:", missing)
    print(f"beyond rtol {args.rtol:g}: {len(bad)}")
    for d, path, a, b in bad[:30]:
        print(f"  {d:.3e}  {path}  ({a!r} / {b!r})")
    return 1 if bad or out["structure"] or out["exact"] or missing else 0


if __name__ == "__main__":
    sys.exit(main())
