"""Launch files: a whole graph from YAML, supervised and stopped cleanly.

Layering inside this package (imports point downwards)::

    supervisor   runs a LaunchPlan: in-process bus, child processes, respawn, staged shutdown, progress
    summary      how the nodes ended: exit texts, the summary, the launch's exit code
    nodeproc     the supervisor's record of one node: its output split into lines, its staged stop
    signals      signals into the supervisor's loop (queued, with a wake-up fd)
    process      one child: own process group, PR_SET_PDEATHSIG, non-blocking output pipe
    progress     the progress bar fed from a topic
    loader       YAML -> LaunchPlan: args, substitutions, includes
    nodecheck    node-class and params validation (the checks that import the node runtime)
    plan         the resolved graph (NodeSpec, LaunchPlan)
    schema       the launch-file format as msgspec Structs (validation and JSON Schema)
    source       YAML with file:line:col marks

The file format is documented in docs/launch.md.
"""

from palpa.launch.loader import load_launch, parse_overrides
from palpa.launch.plan import LaunchPlan, NodeSpec
from palpa.launch.schema import LaunchFile, json_schema
from palpa.launch.supervisor import Supervisor

__all__ = ["LaunchFile", "LaunchPlan", "NodeSpec", "Supervisor", "json_schema", "load_launch", "parse_overrides"]
