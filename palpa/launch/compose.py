"""``palpa launch --in-process``: a plan whose simulated-clock nodes run composed in one process.

The nodes a launch file runs on simulated time (``env: {PALPA_SIM_CLOCK: "1"}``), its clock source
(``palpa.timing.simclock:ClockSource``, replaced by the composition's event-to-event clock) and its recorder (which then
hears every message in process, however fast the simulation goes, instead of through the proxy's queues) become one
``cmd`` entry running ``python -m palpa.timing.compose <run_dir>/composed.json``. Every other entry (a real device, a
``cmd``) stays a process of its own on the bus, where the composed graph publishes everything it does.
"""

from __future__ import annotations

import dataclasses
import json
import sys

from palpa import env as palpa_env
from palpa.errors import LaunchError
from palpa.launch.plan import LaunchPlan, NodeSpec

__all__ = [
    "CLOCK_TARGET", "COMPOSED_NAME", "composable_nodes", "compose_plan", "is_composable", "name_clock_participants",
]

CLOCK_TARGET = "palpa.timing.simclock:ClockSource"
COMPOSED_NAME = "sim"
_SIM_ENV = palpa_env.SIM_CLOCK


def is_composable(spec: NodeSpec) -> bool:
    """A node class on the simulated clock (its entry sets ``PALPA_SIM_CLOCK``)."""
    return spec.target is not None and spec.env.get(_SIM_ENV, "") not in ("", "0")


def name_clock_participants(plan: LaunchPlan) -> None:
    """Tell the file's clock source (unless its entry names them) which nodes run on simulated time: it holds the
    start of time until every one has set up, as a composition builds every node before its first step."""
    names = [s.name for s in plan.nodes if is_composable(s)]
    for spec in plan.nodes:
        if spec.target == CLOCK_TARGET and "participants" not in spec.params:
            spec.params["participants"] = names


def composable_nodes(plan: LaunchPlan) -> list[NodeSpec]:
    """The plan's nodes on the simulated clock, in the file's order (what a composition runs, besides the
    recorder); a :class:`LaunchError` if there is none."""
    composed = [s for s in plan.nodes if is_composable(s)]
    if not composed:
        where = plan.files[0] if plan.files else str(plan.file)
        raise LaunchError(f"{where}: --in-process: no node runs on the simulated clock (an entry with "
                          f"env {{{_SIM_ENV}: \"1\"}}); nothing to compose")
    return composed


def compose_plan(plan: LaunchPlan) -> LaunchPlan:
    """``plan`` with its sim-clock nodes, clock source and recorder replaced by one composed entry (named ``sim``,
    or ``sim-1``... if that name is taken). Writes nothing: the graph description goes into the entry's command
    line; the recorder's parameters come from ``plan.recorder()``."""
    where = plan.files[0] if plan.files else str(plan.file)
    composed = composable_nodes(plan)
    rest = [s for s in plan.nodes if not is_composable(s) and s.target != CLOCK_TARGET]
    members = list(composed)
    rec = plan.recorder()
    if rec is not None:
        if not plan.recorder_available:
            raise LaunchError(f"{where}: the file asks to record, but palpa.record.recorder:Recorder is not "
                              "importable here")
        members.insert(0, rec)  # first: it hears the others from their first message
    env: dict[str, str] = {}
    for s in composed:
        env.update({k: v for k, v in s.env.items() if k != _SIM_ENV})
    graph = {"nodes": [{"name": s.name, "target": s.target, "params": s.params, "namespace": s.namespace,
                        "remap": s.remap, "required": s.required} for s in members]}
    names = {s.name for s in rest}
    name = COMPOSED_NAME
    n = 0
    while name in names:
        n += 1
        name = f"{COMPOSED_NAME}-{n}"
    entry = NodeSpec(
        name=name, cmd=[sys.executable, "-m", "palpa.timing.compose", "--json", json.dumps(graph)],
        env=env, required=any(s.required for s in composed),
        sigterm_timeout=max(s.sigterm_timeout for s in members),
        sigkill_timeout=max(s.sigkill_timeout for s in members),
        where=f"{where}: in_process ({', '.join(s.name for s in members)})", gate=True,
    )
    # a report node composed in goes on being reported: the entry's lines its logger wrote
    inside = {s.name for s in members}
    report = [f"{name}:{r}" if r in inside else r for r in plan.progress_report]
    return dataclasses.replace(plan, nodes=[*rest, entry], record=None, in_process=True, progress_report=report,
                               composed_from=dataclasses.replace(plan, in_process=True).to_yaml())
