"""Compare the values two book builds glued, chapter by chapter (issue 63: same seeds, same numbers).

    .venv/bin/python scripts/diff_glued.py BUILD_A/book/_generated BUILD_B/book/_generated [--out PATH]

Prints one line per chapter (values compared, values that differ) and every differing value; exits 1 when any
value differs or a chapter is missing from one build.  ``--out`` stores the comparison as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from softpend.study.ledger import glued_values


def compare(first: Path, second: Path) -> dict:
    chapters = sorted({p.stem for p in first.glob("*.ipynb")} | {p.stem for p in second.glob("*.ipynb")})
    rows = []
    for name in chapters:
        a, b = glued_values(first / f"{name}.ipynb"), glued_values(second / f"{name}.ipynb")
        differing = {key: [a.get(key), b.get(key)] for key in sorted(set(a) | set(b)) if a.get(key) != b.get(key)}
        rows.append({"chapter": name, "values": len(set(a) | set(b)), "differing": differing})
    return {"first": str(first), "second": str(second), "chapters": rows}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path)
    parser.add_argument("second", type=Path)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    for folder in (args.first, args.second):
        if not folder.is_dir():
            print(f"diff_glued: {folder} is not a folder", file=sys.stderr)
            return 2
    result = compare(args.first, args.second)
    for row in result["chapters"]:
        print(f"{row['chapter']:32s} {row['values']:4d} values, {len(row['differing'])} differ")
        for key, (a, b) in row["differing"].items():
            print(f"    {key}: {a!r} != {b!r}")
    if args.out:
        args.out.write_text(json.dumps(result, indent=1, default=str))
    return 1 if any(row["differing"] for row in result["chapters"]) else 0


if __name__ == "__main__":
    sys.exit(main())
