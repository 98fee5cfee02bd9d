"""Run every benchmark module (`bench_*.py`) in this folder, or those named on the command line."""

import importlib
import pkgutil
import sys
from pathlib import Path

from .common import peak_rss_mb


def main(names: list[str]) -> None:
    here = Path(__file__).parent
    modules = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))
    for name in modules:
        if names and not any(n in name for n in names):
            continue
        print(f"== {name}", flush=True)
        importlib.import_module(f"benchmarks.{name}").run()
    print(f"peak RSS {peak_rss_mb():.0f} MB")


if __name__ == "__main__":
    main(sys.argv[1:])
