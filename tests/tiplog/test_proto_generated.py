"""The committed generated code in tiplog/v1 is exactly what protoc makes from proto/."""

from __future__ import annotations

import filecmp
import subprocess
import sys

from tests.conftest import ROOT


def test_generated_python_matches_proto(tmp_path):
    protos = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "proto").rglob("*.proto"))
    assert protos, "no .proto files found"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "grpc_tools.protoc",
            "-I",
            "proto",
            f"--python_out={tmp_path}",
            f"--pyi_out={tmp_path}",
            *protos,
        ],
        cwd=ROOT,
        check=True,
    )
    generated = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*_pb2.py*"))
    assert generated
    committed = sorted(p.relative_to(ROOT) for p in (ROOT / "tiplog" / "v1").glob("*_pb2.py*"))
    assert generated == committed, "generated file set differs: run `make proto`"
    for rel in generated:
        assert filecmp.cmp(tmp_path / rel, ROOT / rel, shallow=False), f"{rel} is stale: run `make proto`"


def test_every_topic_type_round_trips():
    from tiplog.topics import TOPICS, message_class_by_name

    for topic, cls in TOPICS.items():
        assert (
            message_class_by_name(cls.DESCRIPTOR.full_name) is cls
            or message_class_by_name(cls.DESCRIPTOR.full_name).DESCRIPTOR is cls.DESCRIPTOR
        ), topic
        m = cls()
        assert cls.FromString(m.SerializeToString()) == m
