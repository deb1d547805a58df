"""The examples' tests run in the suite's two tiers too: the in-process tier's guard (tests/conftest.py) applies."""

from tests.conftest import _in_process_tier  # noqa: F401  (an autouse fixture: importing it here applies it)
