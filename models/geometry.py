"""Measured geometry: the sample's thickness as someone measured it, the only geometry the estimator knows.

A rig knows a sample's thickness only as well as someone measured it (calliper, depth gauge, a scan of the
surface). The estimator reads that measurement from a small YAML file, never the phantom (docs/physics.md,
"Measured geometry"). Units mm, phantom frame (origin at a corner, as the robot's scan region)::

    # a constant
    thickness_mm: 20.0
    error_mm: 0.2                 # optional: the measurer's stated 1-sigma uncertainty (informational)
    source: "calliper, 4 points"  # optional free text
    footprint_mm: [0, 0, 80, 50]  # optional: x0, y0, x1, y1 of the specimen on the table, as measured
                                  # (the scanner's default region is it less an edge margin; a map's grid otherwise)

    # or a map: values[iy][ix] at the grid points x_mm[ix], y_mm[iy] (ascending), bilinear in between
    thickness_mm:
      x_mm: [0, 10, 20]
      y_mm: [0, 30, 60]
      values: [[2.0, 2.0, 2.0], [4.0, 4.1, 4.0], [2.0, 2.0, 1.9]]

Outside a map's grid the thickness is nan (the estimator marks such samples ``off_geometry``).

``python -m models.geometry measure PHANTOM.yaml --error-mm 0.2 --seed 0 -o FILE`` is the *simulation's*
measurer: it reads the phantom's true thickness on a grid and adds seeded Gaussian error (per point) plus an
optional systematic ``--bias-mm``, writing both into the file's ``source`` line. It belongs to the sim setup, not
to the graph.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Annotated, Any, ClassVar

import msgspec
import numpy as np
import numpy.typing as npt
import yaml

from models._arrays import ArrayLike
from models._arrays import as_f64 as _f64
from models._arrays import scalar_or_array as _out
from yamlstruct import Source, convert
from yamlstruct.convert import kind

__all__ = ["GeometryError", "MeasuredGeometry", "load_geometry", "measure_phantom", "parse_geometry"]


class GeometryError(ValueError):
    """A measured-geometry file is invalid; the message names the file, the key and why."""


class MeasuredGeometry:
    """Thickness (mm) at phantom-frame (x, y): a constant, or bilinear over a measured grid (nan outside it)."""

    def __init__(self, thickness_mm: float | None = None, *, x_mm: ArrayLike | None = None,
                 y_mm: ArrayLike | None = None, values: ArrayLike | None = None, error_mm: float = math.nan,
                 source: str = "", footprint_mm: tuple[float, float, float, float] | None = None) -> None:
        self.constant = thickness_mm
        self.error_mm = error_mm
        self.source = source
        self.footprint_given = footprint_mm
        if thickness_mm is None:
            if x_mm is None or y_mm is None or values is None:
                raise GeometryError("measured geometry: give a constant thickness or x_mm, y_mm and values")
            # (a grid as parse_geometry checks it: two or more strictly ascending x_mm and y_mm, values[iy][ix])
            self.x_mm, self.y_mm, self.values = _f64(x_mm), _f64(y_mm), _f64(values)

    def thickness(self, x: ArrayLike, y: ArrayLike) -> ArrayLike:
        """Measured thickness (mm) at (x, y); nan off a measured map."""
        xa, ya = np.broadcast_arrays(_f64(x), _f64(y))
        if self.constant is not None:
            return _out(np.full(xa.shape, float(self.constant)), x, y)
        return _out(_bilinear(self.x_mm, self.y_mm, self.values, xa, ya), x, y)

    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        """The specimen's measured footprint (x0, y0, x1, y1): the file's ``footprint_mm``, else a map's grid extent,
        else None (a constant thickness says nothing of where the specimen lies)."""
        if self.footprint_given is not None:
            return self.footprint_given
        if self.constant is not None:
            return None
        return (float(self.x_mm[0]), float(self.y_mm[0]), float(self.x_mm[-1]), float(self.y_mm[-1]))

    def top_mm(self) -> float:
        """The thickest measured point (mm): how high the specimen's surface may reach."""
        return float(self.constant) if self.constant is not None else float(np.max(self.values))

    def to_yaml_data(self) -> dict[str, Any]:
        """The file's mapping (``load_geometry`` reads it back)."""
        data: dict[str, Any]
        if self.constant is not None:
            data = {"thickness_mm": float(self.constant)}
        else:
            data = {"thickness_mm": {"x_mm": self.x_mm.tolist(), "y_mm": self.y_mm.tolist(),
                                     "values": [[round(v, 4) for v in row] for row in self.values.tolist()]}}
        if math.isfinite(self.error_mm):
            data["error_mm"] = self.error_mm
        if self.source:
            data["source"] = self.source
        if self.footprint_given is not None:
            data["footprint_mm"] = [round(v, 3) for v in self.footprint_given]
        return data


def _bilinear(gx: npt.NDArray[np.float64], gy: npt.NDArray[np.float64], values: npt.NDArray[np.float64],
              x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Bilinear interpolation of ``values[iy][ix]`` on the ascending grid (``gx``, ``gy``) at (``x``, ``y``), nan
    outside the grid (its edges included in it). Written out in numpy: scipy.interpolate cost every scanner and
    estimator process a quarter of a second to import, for four multiplications."""
    ix = np.clip(np.searchsorted(gx, x, side="right") - 1, 0, gx.size - 2)
    iy = np.clip(np.searchsorted(gy, y, side="right") - 1, 0, gy.size - 2)
    tx = (x - gx[ix]) / (gx[ix + 1] - gx[ix])
    ty = (y - gy[iy]) / (gy[iy + 1] - gy[iy])
    v00, v01 = values[iy, ix], values[iy, ix + 1]
    v10, v11 = values[iy + 1, ix], values[iy + 1, ix + 1]
    out = (1 - ty) * ((1 - tx) * v00 + tx * v01) + ty * ((1 - tx) * v10 + tx * v11)
    inside = (x >= gx[0]) & (x <= gx[-1]) & (y >= gy[0]) & (y <= gy[-1])
    return np.where(inside, out, np.nan)


class _GeometrySource(Source):
    error_type: ClassVar[type[Exception]] = GeometryError
    document: ClassVar[str] = "the geometry file"


_Finite = Annotated[float, msgspec.Meta(ge=-sys.float_info.max, le=sys.float_info.max)]  # NaN and inf fail
_PositiveMm = Annotated[float, msgspec.Meta(gt=0.0, le=sys.float_info.max)]


class _MapDecl(msgspec.Struct, forbid_unknown_fields=True):
    x_mm: Annotated[list[_Finite], msgspec.Meta(min_length=2)]
    y_mm: Annotated[list[_Finite], msgspec.Meta(min_length=2)]
    values: list[list[_PositiveMm]]


class _GeometryFile(msgspec.Struct, forbid_unknown_fields=True):
    thickness_mm: _PositiveMm | _MapDecl
    error_mm: float = math.nan
    source: str = ""
    footprint_mm: tuple[_Finite, _Finite, _Finite, _Finite] | None = None


def _geometry(src: Source) -> MeasuredGeometry:
    if not isinstance(src.data, dict):
        raise src.error((), f"expected a mapping with thickness_mm, got {kind(src.data)}")
    doc: _GeometryFile = convert(src, src.data, _GeometryFile)
    if not (math.isnan(doc.error_mm) or doc.error_mm >= 0):
        raise src.error(("error_mm",), f"error_mm: expected a number >= 0 (mm), got {doc.error_mm!r}")
    fp = doc.footprint_mm
    if fp is not None and not (fp[0] < fp[2] and fp[1] < fp[3]):
        raise src.error(("footprint_mm",), f"footprint_mm: expected [x0, y0, x1, y1] (mm) with x0 < x1 and y0 < y1, "
                                           f"got {list(fp)!r}")
    t = doc.thickness_mm
    if not isinstance(t, _MapDecl):
        return MeasuredGeometry(t, error_mm=doc.error_mm, source=doc.source, footprint_mm=fp)
    for key in ("x_mm", "y_mm"):
        if not np.all(np.diff(getattr(t, key)) > 0):
            raise src.error(("thickness_mm", key), f"thickness_mm.{key}: expected strictly ascending numbers")
    if len(t.values) != len(t.y_mm) or any(len(row) != len(t.x_mm) for row in t.values):
        raise src.error(("thickness_mm", "values"), f"thickness_mm.values: expected {len(t.y_mm)} rows (one per y_mm) "
                                                    f"of {len(t.x_mm)} values (one per x_mm), got {len(t.values)} rows "
                                                    f"of lengths {[len(row) for row in t.values]}")
    x, y, values = (np.asarray(a, dtype=np.float64) for a in (t.x_mm, t.y_mm, t.values))
    return MeasuredGeometry(x_mm=x, y_mm=y, values=values, error_mm=doc.error_mm, source=doc.source,
                            footprint_mm=fp)


def parse_geometry(data: Any, source: str = "<geometry>") -> MeasuredGeometry:
    """Validate a decoded geometry mapping; errors name ``source`` and the key."""
    return _geometry(_GeometrySource(path=Path(source), name=source, data=data))


def load_geometry(path: str | Path) -> MeasuredGeometry:
    """Read and validate a measured-geometry YAML file through :mod:`yamlstruct` (the project's one YAML loader);
    a :class:`GeometryError` reads ``file:line:col: key: what is wrong``."""
    return _geometry(_GeometrySource.read(Path(path)))


def measure_phantom(phantom: Any, *, error_mm: float, bias_mm: float = 0.0, seed: int = 0,
                    spacing_mm: float = 5.0) -> MeasuredGeometry:
    """The simulation's measurer: the phantom's thickness on a grid (corners included) + N(bias, error²) per point.

    ``phantom`` is a ``models.phantom.Phantom`` (typed loosely so that the estimator's import of this module does
    not pull the world in). A flat phantom gives a map too: its points scatter by error_mm like a real measurement.
    """
    lx, ly = phantom.size_mm
    xs = np.linspace(0.0, lx, max(2, round(lx / spacing_mm) + 1))
    ys = np.linspace(0.0, ly, max(2, round(ly / spacing_mm) + 1))
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    true = np.asarray(phantom.thickness(xx, yy), dtype=np.float64)
    rng = np.random.default_rng(seed)
    measured = np.maximum(true + bias_mm + rng.normal(0.0, error_mm, true.shape), 0.05)
    # the footprint as a ruler gives it: each edge to the nearest 0.5 mm after the same per-point error
    edges = np.round((np.array([0.0, 0.0, lx, ly]) + rng.normal(0.0, error_mm, 4)) * 2) / 2
    src = (f"simulated measurement of {phantom.name or 'a phantom'}: per-point error N(0, {error_mm:g} mm), "
           f"bias {bias_mm:+g} mm, seed {seed}, {spacing_mm:g} mm grid")
    return MeasuredGeometry(x_mm=xs, y_mm=ys, values=measured, error_mm=error_mm, source=src,
                            footprint_mm=(float(edges[0]), float(edges[1]), float(edges[2]), float(edges[3])))


def main(argv: list[str] | None = None) -> int:
    """``python -m models.geometry measure PHANTOM --error-mm E [--bias-mm B] [--seed S] -o FILE``."""
    ap = argparse.ArgumentParser(prog="python -m models.geometry", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="verb", required=True)
    m = sub.add_parser("measure", help="write a measured-geometry file from a phantom, with a seeded error")
    m.add_argument("phantom", type=Path)
    m.add_argument("--error-mm", type=float, default=0.2, help="per-point 1-sigma measurement error (mm)")
    m.add_argument("--bias-mm", type=float, default=0.0, help="systematic error added everywhere (mm)")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--spacing-mm", type=float, default=5.0, help="measurement grid spacing (mm)")
    m.add_argument("-o", "--output", type=Path, required=True)
    args = ap.parse_args(argv)
    from models.phantom import PhantomError, load_phantom

    try:
        ph = load_phantom(args.phantom)
    except PhantomError as exc:
        print(f"geometry: {exc}", file=sys.stderr)
        return 1
    geo = measure_phantom(ph, error_mm=args.error_mm, bias_mm=args.bias_mm, seed=args.seed,
                          spacing_mm=args.spacing_mm)
    header = (f"# Measured geometry (docs/physics.md): written by\n#   python -m models.geometry measure "
              f"{args.phantom} --error-mm {args.error_mm:g} --bias-mm {args.bias_mm:g} --seed {args.seed} "
              f"--spacing-mm {args.spacing_mm:g} -o {args.output}\n")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(header + yaml.safe_dump(geo.to_yaml_data(), sort_keys=False, width=200, default_flow_style=None),
                           encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
