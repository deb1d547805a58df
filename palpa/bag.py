"""Recordings as data: ``palpa.bag.read(path, topics=...)`` gives one pandas DataFrame per topic.

.. code-block:: python

    import palpa.bag

    frames = palpa.bag.read("runs/latest/recording.mcap", topics=["stiffness/sample", "pressure/state"])
    samples = frames["stiffness/sample"]          # one row per message, fields flattened (docs/recording.md)
    table = palpa.bag.align(frames, palpa.bag.AlignSpec(topic="stiffness/sample", method="linear"))

Columns, flattening and units: :mod:`palpa.record.tables`; the aligned table: :class:`AlignSpec`. The same tables
are written to CSV or Parquet by ``palpa bag export FILE --format csv|parquet``.
"""

from palpa.record.table_export import AlignSpec, align
from palpa.record.tables import ENVELOPE_COLUMNS, read

__all__ = ["ENVELOPE_COLUMNS", "AlignSpec", "align", "read"]
