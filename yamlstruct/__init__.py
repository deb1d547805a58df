"""YAML files as msgspec Structs, with ``file:line:col`` in every error: the one YAML loader of the project.

Launch files, parameter files, phantoms and fibre calibrations are read through it. It is a package of its own, importing only
PyYAML and msgspec, so that ``models/`` (pure, no runtime) and ``palpa/`` can both use it without ``models``
importing palpa's runtime (ZeroMQ, the node loop) through ``palpa/__init__``.
"""

from yamlstruct.convert import convert, did_you_mean, load
from yamlstruct.source import Mark, Source, YamlError

__all__ = ["Mark", "Source", "YamlError", "convert", "did_you_mean", "load"]
