"""Render BENCHMARKS.md and the generated tables of docs/reports/*.md from results/*/summary.json.

    python scripts/report.py            # rewrite the files that differ
    python scripts/report.py --check    # exit 1 and name the files that differ (run by the suite)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mjxrmp import _xla
from mjxrmp.results.report import render_all, stale_files
from mjxrmp.results.summary import SummaryError, write_text

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="only compare; exit 1 if a committed file differs from the rendering")
    parser.add_argument("--root", type=Path, default=ROOT, help="repository root")
    args = parser.parse_args(argv)
    try:
        rendered = render_all(args.root)
        stale = stale_files(rendered)
        if args.check:
            for path in stale:
                print(f"stale: {path.relative_to(args.root)} (run python scripts/report.py)")
            return 1 if stale else 0
        for path in stale:
            write_text(path, rendered[path])
            print(f"wrote {path.relative_to(args.root)}")
    except SummaryError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
