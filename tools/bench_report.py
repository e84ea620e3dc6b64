#!/usr/bin/env python3
"""Prints criterion medians for one benchmark group and their ratios to the
group's `reference_*` function at the same input size.

usage: python3 tools/bench_report.py GROUP [TARGET_DIR]
"""
import json
import pathlib
import sys


def main() -> int:
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    group = sys.argv[1]
    target = pathlib.Path(sys.argv[2] if len(sys.argv) > 2 else "target")
    root = target / "criterion" / group
    if not root.is_dir():
        print(f"no criterion results under {root}: run `cargo bench --bench {group}` first", file=sys.stderr)
        return 1
    medians = {}  # (function, input) -> seconds
    for est in root.glob("*/*/new/estimates.json"):
        function, size = est.parts[-4], est.parts[-3]
        medians[(function, size)] = json.loads(est.read_text())["median"]["point_estimate"] * 1e-9
    sizes = sorted({s for _, s in medians}, key=lambda s: [int(v) for v in s.split("x")])
    functions = sorted({f for f, _ in medians})
    references = [f for f in functions if f.startswith("reference")]
    print(f"| {group} | " + " | ".join(sizes) + " |")
    print("|---|" + "---|" * len(sizes))
    for f in functions:
        cells = []
        for s in sizes:
            t = medians.get((f, s))
            if t is None:
                cells.append("-")
                continue
            cell = f"{t * 1e3:.3f} ms"
            ref = medians.get((references[0], s)) if references else None
            if ref and f not in references:
                cell += f" ({t / ref:.0f}x ref)"
            cells.append(cell)
        print(f"| {f} (median) | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
