"""The suite's session fixtures, for the accuracy checks run on their own (`make accuracy`)."""

from tests.conftest import _bench_pass_cache  # noqa: F401  (autouse: benches cache in the session)
