"""A node module that fails at import time (for the launch error corpus)."""

raise RuntimeError("this module is broken on purpose")
