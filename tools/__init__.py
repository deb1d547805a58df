"""Tools a user runs beside a graph (not nodes): calibrations, the scan report, the batch evaluation."""
