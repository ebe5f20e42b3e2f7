"""Run every benchmark module in this folder in turn."""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path


def main() -> int:
    here = Path(__file__).parent
    names = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if not m.name.startswith("_"))
    for name in names:
        print(f"== benchmarks.{name}")
        mod = importlib.import_module(f"benchmarks.{name}")
        rc = mod.main([]) if hasattr(mod, "main") else 0
        if rc:
            return rc
    return 0


if __name__ == "__main__":
    sys.exit(main())
