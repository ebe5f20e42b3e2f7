"""The filter's parameters as files and text, outside the filter core (which reads no files):
a `--params` file read (`load_params`), and the built-in set written out from `Params`' own
field docstrings, as a `--params` file (`defaults_yaml`, `tiplog fusion params`) and as the
table of docs/fusion.md (`markdown_table`), so that neither can go stale."""

from __future__ import annotations

import ast
import inspect
import textwrap
from dataclasses import fields
from pathlib import Path
from typing import Any

from services.fusion.eskf.params import Params, ParamsError
from tiplog.userio import read_yaml


def load_params(path: str | Path) -> Params:
    """A YAML mapping of parameter names (optionally under `fusion_params:`); ParamsError
    naming the file and what is wrong."""
    p = Path(path)
    doc = read_yaml(p, ParamsError, "not a text/YAML file (a parameter file is YAML)")
    if isinstance(doc, dict) and "fusion_params" in doc:
        doc = doc["fusion_params"]
    return Params.from_dict(doc or {}, where=str(p))


_UNITS = (
    ("_dps_rts_per_radps", "deg/s/sqrt(s) per rad/s"),
    ("_dps_rthz", "deg/s/sqrt(Hz)"),
    ("_dps_rts", "deg/s/sqrt(s)"),
    ("_mps2_rthz", "m/s^2/sqrt(Hz)"),
    ("_mps2_rts", "m/s^2/sqrt(s)"),
    ("_mm2_per_deg", "mm^2/deg"),
    ("_mm_rts", "mm/sqrt(s)"),
    ("_mps2", "m/s^2"),
    ("_mps", "m/s"),
    ("_dps", "deg/s"),
    ("_deg", "deg"),
    ("_mm", "mm"),
    ("_ms", "ms"),
    ("_m", "m"),
    ("_s", "s"),
)


def unit(name: str) -> str:
    """A parameter's unit, read from its name's suffix ("" for counts, factors and switches)."""
    return next((u for suffix, u in _UNITS if name.endswith(suffix)), "")


def field_docs() -> dict[str, str]:
    """Each field's one-line description: the string literal under it in `Params`."""
    cls = ast.parse(textwrap.dedent(inspect.getsource(Params))).body[0]
    if not isinstance(cls, ast.ClassDef):
        raise TypeError("Params' source is not a class")
    out: dict[str, str] = {}
    for node, after in zip(cls.body, cls.body[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(after, ast.Expr)
            and isinstance(after.value, ast.Constant)
            and isinstance(after.value.value, str)
        ):
            out[node.target.id] = " ".join(after.value.value.split())
    return out


def _value(v: Any) -> str:
    return ("true" if v else "false") if isinstance(v, bool) else f"{v:g}" if isinstance(v, float) else str(v)


def markdown_table() -> str:
    """The parameter table of docs/fusion.md: name, unit, default, what it does."""
    docs = field_docs()
    rows = ["| parameter | unit | default | what it does |", "| --- | --- | --- | --- |"]
    for f in fields(Params):
        what = docs.get(f.name, "").replace("|", "\\|")
        rows.append(f"| `{f.name}` | {unit(f.name)} | {_value(f.default)} | {what} |")
    return "\n".join(rows) + "\n"


def defaults_yaml() -> str:
    """The built-in parameters as a `--params` file, each with its unit and description."""
    docs = field_docs()
    out = [
        "# tiplog fusion parameters: the built-in set. Keep the lines you change; pass with --params.",
        "fusion_params:",
    ]
    for f in fields(Params):
        u = unit(f.name)
        out.append(f"  {f.name}: {_value(f.default)}  # {f'[{u}] ' if u else ''}{docs.get(f.name, '')}")
    return "\n".join(out) + "\n"
