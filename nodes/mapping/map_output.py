"""Writing a scan's outputs (the file formats are a contract other tools read, see DESIGN.md):

* ``map.npz``: ``stiffness`` (ny, nx) grid (NaN = no data), ``x_mm`` (nx) and ``y_mm`` (ny) cell centres,
  ``count`` (ny, nx) samples per cell; plus ``spread`` (robust σ per cell), ``unit`` and ``model`` (0-d strings:
  the estimator's model, ``airfloat`` or ``multi_indenter``, which picks the detector's false-alarm law).
* ``map.png``: heat map with axes in mm, detected inclusions circled, a title naming the run (cells between
  raster lines are shown as their neighbours' median; ``map.npz`` keeps them NaN).
* ``inclusions.json``: a list of ``{x_mm, y_mm, radius_mm, contrast}``, each with the detector's ``snr`` (σ of the
  filtered noise) and ``false_alarm`` (the chance that a map without inclusions shows a peak that significant) when
  known (models.detector).

``map.png`` costs matplotlib's import (~0.3 s) and a render: a node that knows it will write one can start a
:class:`PngHelper` at set-up, a process that imports matplotlib while the scan runs (on another core) and later
draws the picture from ``map.npz``; the picture is the same to the byte, and drawn here if the helper fails.

An adaptive scan also passes ``unsensed`` (the cells where an inclusion of the smallest size of interest could lie
unseen when it stopped: models.adaptive_detect.unsensed): ``map.npz`` keeps it as a bool grid of that name and
``map.png`` greys those cells over the map. It keeps what its detection rule needs to run again too: the grids it
detected from (``layers``: ``measured``, ``fair``) and its settings (``planner``, a 0-d JSON string of its parameters
and region); :func:`redetect` is the whole-map detector and knows nothing of them: a planner's map is detected again
by nodes.scanner.planner_map.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import subprocess
import sys
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from messages import DetectedInclusion, Inclusions
from models.detector import Detection, DetectorConfig, detect, with_law_of
from models.stiffness_map import Inclusion, MapSnapshot, fill_gaps, to_inclusions_json
from palpa.atomic import write_beside, written_beside
from palpa.exiting import exit_now

__all__ = ["MapNotWritten", "PngHelper", "detection_summary", "inclusions_message", "map_incomplete", "map_model",
           "read_map", "redetect", "write_outputs"]


def read_map(npz: Path) -> MapSnapshot:
    """A written ``map.npz`` as the map snapshot it was written from (what models.detector.detect reads); raises
    OSError, KeyError or ValueError on a file that is not one."""
    with np.load(npz) as d:
        x = np.asarray(d["x_mm"], dtype=np.float64)
        y = np.asarray(d["y_mm"], dtype=np.float64)
        grid = np.asarray(d["stiffness"], dtype=np.float64)
        if grid.shape != (y.size, x.size):
            raise ValueError(f"{npz}: stiffness {grid.shape} is not y_mm x x_mm ({y.size}, {x.size})")
        step = np.diff(x) if x.size > 1 else np.diff(y)
        spread = np.asarray(d["spread"], dtype=np.float64) if "spread" in d else np.full(grid.shape, np.nan)
        return MapSnapshot(grid, x, y, np.asarray(d["count"], dtype=np.int64), spread,
                           float(step[0]) if step.size else 1.0)


_MODEL_OF_UNIT = {"kPa": "airfloat", "N/mm": "multi_indenter"}
"""A map written before ``model`` was stored is told by its unit: the air-float's E, the camera probe's K_t."""


def map_model(npz: Path) -> str:
    """The model of the estimator whose samples a written ``map.npz`` holds (``model``, else told by ``unit``); ''
    when neither says."""
    with np.load(npz) as d:
        if "model" in d:
            return str(d["model"])
        return _MODEL_OF_UNIT.get(str(d["unit"]), "") if "unit" in d else ""


def map_incomplete(npz: Path) -> str:
    """Why a written ``map.npz`` lacks part of what it was to hold (its ``incomplete``; '' when it is whole): a map
    scored or reported later must say so, and count as a failed run."""
    with np.load(npz) as d:
        return str(d["incomplete"]) if "incomplete" in d else ""


def redetect(npz: Path, cfg: DetectorConfig | None = None) -> Detection:
    """The map detector (models.detector.detect, the map aggregator's) run on a written ``map.npz`` again, with the
    false-alarm law of the probe that made the map (:func:`map_model`; a probe without one: ``cfg``'s): a raster's
    rule, which an adaptive planner's map was not detected by (nodes.scanner.planner_map.redetect_map tells them
    apart). Raises OSError, KeyError or ValueError on a file that is not a map."""
    return detect(read_map(npz), with_law_of(cfg or DetectorConfig(), map_model(npz)))


def inclusions_message(det: Detection, *, stamp_ns: int, unit: str, false_alarm_per_map: float,
                       final: bool) -> Inclusions:
    """The ``map/inclusions`` message of a detection (the raster's map and the adaptive planner's alike)."""
    return Inclusions(
        stamp_ns=stamp_ns, unit=unit, baseline=float(det.baseline), final=final,
        threshold_snr=float(det.threshold_snr) if math.isfinite(det.threshold_snr) else 0.0,
        false_alarm_per_map=false_alarm_per_map,
        inclusions=[DetectedInclusion(x_mm=i.x_mm, y_mm=i.y_mm, radius_mm=i.radius_mm, contrast=i.contrast,
                                      snr=i.snr, false_alarm=i.false_alarm) for i in det.inclusions])


def detection_summary(det: Detection, false_alarm_per_map: float) -> str:
    """One line for a map's title: how many inclusions, each one's significance, and the threshold they passed."""
    n = len(det.inclusions)
    if not math.isfinite(det.threshold_snr):
        return f"{n} inclusion(s) (too little map to detect on)"
    snrs = ", ".join(f"{i.snr:.1f}" for i in det.inclusions)
    return (f"{n} inclusion(s)" + (f" at SNR {snrs}" if n else "")
            + f"; threshold {det.threshold_snr:.1f} σ ({100 * false_alarm_per_map:g} % false alarms per blank map)")

log = logging.getLogger(__name__)
_REPO = Path(__file__).resolve().parents[len(__name__.split(".")) - 1]
"""Where ``python -m`` finds this module (the helper runs it by its own name, wherever it lives)."""
_HELPER_TIMEOUT_S = 60.0
"""Wall seconds the helper may take to draw (it is then killed, and the picture drawn here)."""


class PngHelper:
    """A process that has imported matplotlib and waits to draw one ``map.png`` (this module run with ``python -m``,
    reading one JSON request on stdin). Started at once; :meth:`close` ends it if it was not used."""

    def __init__(self) -> None:
        self._proc: subprocess.Popen[str] | None = subprocess.Popen(
            [sys.executable, "-m", __name__], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            cwd=_REPO, process_group=0)  # its own group: the Ctrl-C that asks the node to write its map must not
        # kill the helper that draws it (it ends by itself at the end of its input if the node dies)

    def render(self, npz: Path, png: Path, inclusions: Sequence[Inclusion], *, unit: str, title: str,
               resolution_mm: float) -> bool:
        """Have the helper draw ``png`` from ``npz`` (written before); whether it did (it serves once)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return False
        request = {"npz": str(npz.absolute()), "png": str(png.absolute()), "unit": unit, "title": title,
                   "resolution_mm": resolution_mm,
                   "inclusions": [[float(i.x_mm), float(i.y_mm), float(i.radius_mm), float(i.contrast)]
                                  for i in inclusions]}
        try:
            out, _ = proc.communicate(json.dumps(request) + "\n", timeout=_HELPER_TIMEOUT_S)
        except (OSError, subprocess.TimeoutExpired) as exc:
            log.warning("map.png helper failed (%s): drawing it here", exc)
            _end(proc)
            return False
        if proc.returncode != 0 or out.strip() != "ok":
            log.warning("map.png helper failed (exit code %s): drawing it here", proc.returncode)
            return False
        return True

    def close(self) -> None:
        """End the helper if it is still waiting."""
        proc, self._proc = self._proc, None
        if proc is not None:
            _end(proc)


def _end(proc: subprocess.Popen[str]) -> None:
    stdin: IO[str] | None = proc.stdin
    if stdin is not None:
        with contextlib.suppress(OSError):
            stdin.close()  # end of input: an idle helper exits by itself
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _serve() -> int:
    """The helper's side: import matplotlib now, then draw the one picture asked for on stdin."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401  (the cost paid ahead, while the scan runs)
    from matplotlib.patches import Circle  # noqa: F401

    line = sys.stdin.readline()
    if not line:
        return 0  # the node closed without a map to draw
    req = json.loads(line)
    with np.load(req["npz"]) as z:
        snap = MapSnapshot(stiffness=z["stiffness"], x_mm=z["x_mm"], y_mm=z["y_mm"], count=z["count"],
                           spread=z["spread"], resolution_mm=float(req["resolution_mm"]))
        unsensed = z.get("unsensed")
    found = [Inclusion(x_mm=x, y_mm=y, radius_mm=r, contrast=c, peak=0.0, area_mm2=0.0, cells=0)
             for x, y, r, c in req["inclusions"]]
    write_beside(Path(req["png"]), _render_png(snap, found, unit=req["unit"], title=req["title"],
                                               unsensed=unsensed))
    print("ok", flush=True)
    return 0


class MapNotWritten(OSError):
    """The map's files could not be written (a full disk, a read-only or vanished folder): the message names the
    folder and the error. A node that gets it has no map to show for its scan and must not end as if it had one."""


_ARRAYS = ("stiffness", "x_mm", "y_mm", "count", "spread", "unit", "model", "unsensed", "incomplete", "planner")
"""The arrays :func:`write_outputs` writes to ``map.npz`` itself: no layer may take their names."""


def write_outputs(out_dir: Path, snap: MapSnapshot, inclusions: Sequence[Inclusion], *, unit: str,
                  title: str, unsensed: npt.NDArray[np.bool_] | None = None, incomplete: str = "",
                  helper: PngHelper | None = None, model: str = "",
                  layers: Mapping[str, npt.NDArray[np.float64]] | None = None, planner: str = "") -> list[Path]:
    """Write the three files (each atomically: a reader never sees half a file); returns their paths.
    ``model``: the estimator's model (kept in ``map.npz`` when given: it picks the false-alarm law a redetection uses).
    ``unsensed``: a bool grid of the map's shape, kept in ``map.npz`` and greyed in ``map.png`` (module doc).
    ``incomplete``: why the map lacks part of what it was to hold ('' when it does not): kept in ``map.npz``
    (``incomplete``) and written over ``map.png``'s title, so that a partial map read later says so.
    ``helper``: draws ``map.png`` if it can (:class:`PngHelper`). ``layers``: more grids of the map's shape kept in
    ``map.npz`` under their names (an adaptive planner's measured and stiffness-blind cells: what its detection
    used, so that it can be run again offline). ``planner``: an adaptive planner's settings (JSON,
    nodes.scanner.planner_map.planner_settings), kept in ``map.npz`` under that name when given: with the layers,
    what its detection rule is rebuilt from. Raises :class:`MapNotWritten` when a file cannot be written."""
    if unsensed is not None and np.shape(unsensed) != np.shape(snap.stiffness):
        raise ValueError(f"unsensed: shape {np.shape(unsensed)} is not the map's {np.shape(snap.stiffness)}")
    for name, grid in (layers or {}).items():
        if name in _ARRAYS:
            raise ValueError(f"layer {name!r}: map.npz has an array of that name")
        if np.shape(grid) != np.shape(snap.stiffness):
            raise ValueError(f"layer {name!r}: shape {np.shape(grid)} is not the map's {np.shape(snap.stiffness)}")
    npz = out_dir / "map.npz"
    arrays: dict[str, Any] = {
        "stiffness": snap.stiffness, "x_mm": snap.x_mm, "y_mm": snap.y_mm, "count": snap.count,
        "spread": snap.spread, "unit": np.array(unit)}
    if model:
        arrays["model"] = np.array(model)
    if planner:
        arrays["planner"] = np.array(planner)
    if unsensed is not None:
        arrays["unsensed"] = np.asarray(unsensed, dtype=bool)
    arrays.update({name: np.asarray(grid, dtype=np.float64) for name, grid in (layers or {}).items()})
    if incomplete:
        arrays["incomplete"] = np.array(incomplete)
        title = "\n".join(textwrap.wrap(f"INCOMPLETE: {incomplete}", 90)) + "\n" + title
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with written_beside(npz) as tmp, open(tmp, "wb") as fh:  # a file, not a name: np.savez would add .npz
            np.savez_compressed(fh, **arrays)
        js = out_dir / "inclusions.json"
        write_beside(js, json.dumps(to_inclusions_json(inclusions), indent=2) + "\n")
        png = out_dir / "map.png"
        if helper is None or not helper.render(npz, png, inclusions, unit=unit, title=title,
                                               resolution_mm=snap.resolution_mm):
            write_beside(png, _render_png(snap, inclusions, unit=unit, title=title, unsensed=unsensed))
        return [npz, png, js]
    except OSError as exc:   # a full disk, a read-only or vanished folder
        raise MapNotWritten(f"the map could not be written to {out_dir}: {exc}") from exc


def _render_png(snap: MapSnapshot, inclusions: Sequence[Inclusion], *, unit: str, title: str,
                unsensed: npt.NDArray[np.bool_] | None = None) -> bytes:
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    r = snap.resolution_mm
    extent = (float(snap.x_mm[0] - r / 2), float(snap.x_mm[-1] + r / 2),
              float(snap.y_mm[0] - r / 2), float(snap.y_mm[-1] + r / 2))
    fig, ax = plt.subplots(figsize=(6.4, 5.4), dpi=100)
    # cells between raster lines have no samples; show them as their neighbours' median (map.npz keeps NaN)
    data = np.ma.masked_invalid(fill_gaps(np.asarray(snap.stiffness, dtype=float)))
    im = ax.imshow(data, origin="lower", extent=extent, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, label=f"stiffness ({unit})")
    if unsensed is not None and np.any(unsensed):
        grey = np.zeros((*np.shape(unsensed), 4))
        grey[np.asarray(unsensed, dtype=bool)] = (0.55, 0.55, 0.55, 0.75)
        ax.imshow(grey, origin="lower", extent=extent, interpolation="nearest")
        title += (f"\ngrey ({100 * np.mean(unsensed):.1f} % of the map): an inclusion of the smallest size of "
                  "interest could lie there unsensed")
    for i, inc in enumerate(inclusions, 1):
        ax.add_patch(Circle((inc.x_mm, inc.y_mm), inc.radius_mm, fill=False, color="red", lw=1.5))
        label = f"{i}: ×{inc.contrast:.2f}" + (f", {inc.snr:.1f} σ" if math.isfinite(inc.snr) else "")
        ax.annotate(label, (inc.x_mm, inc.y_mm + inc.radius_mm + 0.8), color="red",
                    ha="center", fontsize=8)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title, fontsize=9)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


if __name__ == "__main__":
    # without the interpreter's teardown (~0.1 s with matplotlib loaded), which the node waits for at the scan's
    # end; the picture is written whole by then
    exit_now(_serve())
