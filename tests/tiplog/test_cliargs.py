"""Option value types: a value out of range or not finite is refused with why."""

from __future__ import annotations

import argparse

import pytest

from tiplog.cliargs import endpoint, finite, whole


def test_whole():
    assert whole(0)("3") == 3 and whole(1, 5)("5") == 5
    for text, needle in (("-1", "must be >= 0 (got -1)"), ("2.5", "expected a whole number"), ("x", "'x'")):
        with pytest.raises(argparse.ArgumentTypeError, match=needle.replace("(", r"\(").replace(")", r"\)")):
            whole(0)(text)
    with pytest.raises(argparse.ArgumentTypeError, match="must be >= 1 and <= 5"):
        whole(1, 5)("6")


def test_finite():
    assert finite(0, lo_open=True)("1e-3") == 1e-3 and finite(0, 10)("0") == 0.0
    for text in ("nan", "inf", "-inf", "NaN"):
        with pytest.raises(argparse.ArgumentTypeError, match="must be a finite number"):
            finite()(text)
    with pytest.raises(argparse.ArgumentTypeError, match="must be > 0"):
        finite(0, lo_open=True)("0")
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be >= 0.001 and <= 1000 \(got 1e-9\)"):
        finite(0.001, 1000)("1e-9")
    with pytest.raises(argparse.ArgumentTypeError, match="expected a number"):
        finite()("fast")


def test_endpoint():
    assert endpoint()("tcp/127.0.0.1:7447") == "tcp/127.0.0.1:7447"
    assert endpoint(listening=True)("tcp/127.0.0.1:0") == "tcp/127.0.0.1:0"
    with pytest.raises(argparse.ArgumentTypeError, match="not an IPv4 address"):
        endpoint()("tcp/999.1.1.1:1")


def test_an_empty_listen_endpoint_means_none():
    """`--listen ''` (README, docs/deployment.md): a client that only connects listens nowhere."""
    from tiplog.service import add_config_arguments, overrides_from_args

    p = argparse.ArgumentParser()
    add_config_arguments(p)
    args = p.parse_args(["--mode", "client", "--connect", "tcp/127.0.0.1:7447", "--listen", ""])
    assert ("bus.listen", []) in overrides_from_args(args)
    with pytest.raises(SystemExit):
        p.parse_args(["--listen", "tcp/"])
