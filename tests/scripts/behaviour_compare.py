"""Largest relative differences between two behaviour snapshots (behaviour_snapshot.py)."""
import json, sys, numpy as np
a, b = (json.load(open(p)) for p in sys.argv[1:3])
def walk(x, y, path=""):
    if isinstance(x, dict):
        for k in x: yield from walk(x[k], y[k], path + "/" + k)
    else:
        x, y = np.asarray(x, float), np.asarray(y, float)
        yield path, float(np.max(np.abs(x - y) / np.maximum(np.abs(x), 1e-300))) if x.size else 0.0, x.size
worst = sorted(walk(a, b), key=lambda t: -t[1])
print("values compared:", sum(n for _, _, n in worst), "; largest relative differences:")
for p, d, n in worst[:5]: print(f"  {d:.3e}  {p}")
