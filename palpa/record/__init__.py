"""Recording and replay of bus traffic in MCAP files (``palpa record``, ``palpa play``, ``palpa bag``).

Layering inside this package (imports point downwards only)::

    recorder, player     Nodes: the bus side (subscribe_raw -> file, file -> publish_raw)
    info, export, recover  offline tools over finished or damaged files
    tables, table_export   a recording as DataFrames, CSV or Parquet (palpa.bag.read, bag export --format)
    edit                   filter, cut, merge: new recordings from old ones
    reader               streams a bag (one file or a split set) back as BagMessage items
    writer               BagWriter: one MCAP file, chunked, indexed, crash-tolerant
    format               the conventions every layer above shares (names, metadata keys, schemas)

A recording holds the wire payloads exactly as received (message encoding ``msgpack``), the envelope's sequence
number, the publisher's name and type, a JSON Schema per message type, the palpa version, the node list and the
resolved launch file, so it can be read without the code that wrote it. See docs/recording.md.
"""

from palpa.record.format import BagError
from palpa.record.reader import BagMessage, iter_bag, resolve_bag_paths
from palpa.record.writer import BagWriter

__all__ = ["BagError", "BagMessage", "BagWriter", "iter_bag", "resolve_bag_paths"]
