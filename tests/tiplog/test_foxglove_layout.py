"""The shipped Foxglove layout parses, every panel is placed, and it names only topics tiplog
publishes (tiplog/topics.py), fields those messages have, and frames the services send."""

from __future__ import annotations

import json
import re

from services.fusion.live.publish import CHILD_FRAME, PARENT_FRAME
from tests.conftest import ROOT
from tiplog.topics import TOPICS

LAYOUT = ROOT / "config" / "foxglove_layout.json"
FRAMES = {PARENT_FRAME, CHILD_FRAME, "tool", "camera"}  # fusion/tf and bench/tf


def _leaves(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    return _leaves(node["first"]) + _leaves(node["second"])


def _script_topics(layout: dict) -> tuple[set[str], set[str]]:
    """(inputs, outputs) of the layout's user scripts."""
    ins, outs = set(), set()
    for node in layout["userNodes"].values():
        src = node["sourceCode"]
        ins |= set(re.findall(r'"([^"]+)"', re.search(r"export const inputs = \[(.*?)\]", src).group(1)))
        outs.add(re.search(r'export const output = "([^"]+)"', src).group(1))
    return ins, outs


def _check_field(topic: str, fields: str) -> None:
    desc = TOPICS[topic].DESCRIPTOR
    for name in fields.split("."):
        assert name in desc.fields_by_name, f"{topic} has no field {name!r}"
        f = desc.fields_by_name[name]
        desc = f.message_type if f.message_type is not None else None


def test_layout_parses_and_names_only_tiplog_topics():
    layout = json.loads(LAYOUT.read_text())
    panels = layout["configById"]
    assert sorted(_leaves(layout["layout"])) == sorted(panels)  # every panel placed, none dangling
    kinds = {pid.split("!")[0] for pid in panels}
    assert {"3D", "Plot", "Image", "RawMessages"} <= kinds
    ins, outs = _script_topics(layout)
    named: set[str] = set(ins)
    for pid, cfg in panels.items():
        kind = pid.split("!")[0]
        if kind == "3D":
            named |= set(cfg["topics"])
            frames = {k.removeprefix("frame:") for k in cfg["transforms"]}
            assert frames <= FRAMES, frames - FRAMES
            assert cfg["followTf"] in FRAMES
        elif kind == "Plot":
            for p in cfg["paths"]:
                topic, _, fields = p["value"].partition(".")
                if topic in outs:
                    continue
                named.add(topic)
                _check_field(topic, fields)
        elif kind == "Image":
            named.add(cfg["imageMode"]["imageTopic"])
        elif kind == "RawMessages":
            named.add(cfg["topicPath"])
    unknown = named - set(TOPICS)
    assert not unknown, f"the layout names topics tiplog does not publish: {sorted(unknown)}"
    # what the issue asks the layout to show
    assert {"fusion/tf", "bench/tf", "fusion/scene"} <= set(panels["3D!tiplog"]["topics"])
    plotted = {
        p["value"].partition(".")[0] + "." + p["value"].partition(".")[2]
        for c in panels.values()
        for p in c.get("paths", [])
    }
    for field in ("depth_mm", "tilt_deg", "roll_deg"):
        assert f"fusion/state.{field}" in plotted
    assert any(v.startswith("/studio_script/tip_error") for v in plotted)
    assert "vision/preview" in named and "fusion/diagnostics" in named
