"""matplotlib (extra `plots`) for the commands that write PNG figures: imported only when a plot
is asked for, on the Agg backend (files only, no display)."""

from __future__ import annotations

from pathlib import Path

from tiplog.userio import atomic_output


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: Path, force: bool = True) -> Path:
    """Lay the figure out, write it as PNG (under a temporary name, renamed when complete; an
    existing file only replaced with `force`) and free it."""
    fig.tight_layout()
    try:
        with atomic_output(path, force) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        pyplot().close(fig)
    return path
