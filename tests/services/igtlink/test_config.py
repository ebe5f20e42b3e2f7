"""The OpenIGTLink service's configuration: what it refuses before serving."""

from __future__ import annotations

import pydantic
import pytest

from services.igtlink.app import IgtlinkConfig


def test_a_host_off_loopback_needs_allow_remote():
    """OpenIGTLink has no authentication: serving a network is asked for explicitly."""
    assert IgtlinkConfig(host="localhost").host == "localhost"
    assert IgtlinkConfig(host="::1").host == "::1"
    with pytest.raises(pydantic.ValidationError, match="allow_remote"):
        IgtlinkConfig(host="0.0.0.0")
    assert IgtlinkConfig(host="0.0.0.0", allow_remote=True).allow_remote
