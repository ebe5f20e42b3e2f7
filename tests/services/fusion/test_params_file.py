"""The parameter table of docs/fusion.md and `tiplog fusion params` come from Params itself, so
neither can go stale: every field has its one-line description, unit and default there; the
printed defaults read back as a parameter file give the built-in set."""

from __future__ import annotations

import re
from dataclasses import fields
from pathlib import Path

import pytest

from services.fusion.eskf.params import Params
from services.fusion.params_file import defaults_yaml, field_docs, load_params, markdown_table, unit
from tiplog.cli import main

DOC = Path(__file__).resolve().parents[3] / "docs" / "fusion.md"
BEGIN, END = "<!-- params:begin -->\n", "<!-- params:end -->"


def _doc_table() -> str:
    text = DOC.read_text()
    return text[text.index(BEGIN) + len(BEGIN) : text.index(END)]


def test_every_field_says_what_it_is_in_one_line_without_tuning_history():
    docs = field_docs()
    assert set(docs) == {f.name for f in fields(Params)}
    for name, doc in docs.items():
        assert doc and "\n" not in doc, name
        # how a value was found goes in the issue notes, not beside the value
        assert not re.search(r"\bseeds?\b|->|\btuned\b", doc, re.IGNORECASE), (name, doc)


def test_the_doc_table_is_the_generated_one():
    table = _doc_table()
    assert table == markdown_table(), (
        "docs/fusion.md is stale: paste `tiplog fusion params --markdown` between the markers"
    )
    for f in fields(Params):
        assert f"| `{f.name}` |" in table, f.name


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("output_delay_ms", "ms"),
        ("gyro_bias_rw_dps_rts_per_radps", "deg/s/sqrt(s) per rad/s"),
        ("tof_offset_rw_mm2_per_deg", "mm^2/deg"),
        ("accel_noise_mps2_rthz", "m/s^2/sqrt(Hz)"),
        ("depth_min_m", "m"),
        ("noise_adapt_tau_s", "s"),
        ("rest_bias", ""),
        ("gate_chi2_1", ""),
    ],
)
def test_units_come_from_the_names(name, expected):
    assert unit(name) == expected


def test_the_printed_defaults_are_a_params_file_that_gives_the_built_in_set(tmp_path, capsys):
    assert main(["fusion", "params"]) == 0
    out = capsys.readouterr().out
    assert out == defaults_yaml()
    path = tmp_path / "params.yaml"
    path.write_text(out)
    assert load_params(path) == Params()
    assert main(["fusion", "params", "--markdown"]) == 0
    assert capsys.readouterr().out == markdown_table()
