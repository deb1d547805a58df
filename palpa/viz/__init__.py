"""Live visualisation: the bus served to the Foxglove app over its WebSocket protocol (foxglove-sdk).

``palpa viz`` runs :class:`~palpa.viz.bridge.Bridge`; :mod:`palpa.viz.server` is its WebSocket side and
:mod:`palpa.viz.schema` turns palpa's JSON Schemas into the form Foxglove reads. Nothing here knows what the
messages mean: domain views (maps as grids, plans as lines) are ordinary nodes that publish Foxglove-shaped
messages on the bus.
"""

from palpa.viz.bridge import Bridge, BridgeParams
from palpa.viz.server import STATS_TOPIC, SUBPROTOCOL

__all__ = ["Bridge", "BridgeParams", "STATS_TOPIC", "SUBPROTOCOL"]
