"""The map: the aggregator that builds the stiffness map and finds inclusions, its outputs, Foxglove views."""
