"""What runs a batch evaluation makes (``tools.evaluate``): every phantom x seed x ``--arg`` combination as a
:class:`RunSpec`, with the overrides the launch file can take: the phantom, a simulated thickness measurement of it
(written under ``OUT/geometry``), the seed, a raster region inside it and a probe height above it, each only if the
launch file declares that arg. Split from tools.evaluate, which runs and scores them."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from models.geometry import measure_phantom
from models.phantom import load_phantom

__all__ = ["RunSpec", "plan_runs"]


@dataclass
class RunSpec:
    """One launch of the batch: which phantom, seed and arg values, and where it runs."""

    id: str
    phantom: Path
    seed: int
    args: dict[str, Any]
    """The varied ``--arg`` values of this run (the combination it belongs to)."""
    overrides: dict[str, Any] = field(default_factory=dict)
    """Every ``name:=value`` given to the launch (the varied args included)."""
    run_dir: Path = Path()


def _declared_args(launch: Path) -> set[str]:
    from palpa.launch import load_launch

    return set(load_launch(launch, {}, run_dir=Path("runs") / "unused").args)


def plan_runs(launch: Path, phantoms: Sequence[Path], seeds: Sequence[int], grid: dict[str, list[Any]],
              out: Path, *, margin_mm: float | None, geometry_error_mm: float) -> list[RunSpec]:
    """Every phantom x seed x arg combination, with the overrides the launch file can take (module doc)."""
    declared = _declared_args(launch)
    unknown = sorted(set(grid) - declared)
    if unknown:
        raise SystemExit(f"{launch}: no arg named {', '.join(unknown)} (it declares {', '.join(sorted(declared))})")
    if "phantom" not in declared:
        raise SystemExit(f"{launch}: declares no 'phantom' arg: the runner cannot give it a world")
    combos = [dict(zip(grid, values, strict=True)) for values in itertools.product(*grid.values())] or [{}]
    (out / "geometry").mkdir(parents=True, exist_ok=True)
    specs = []
    for ph_path in phantoms:
        ph = load_phantom(ph_path)
        for seed in seeds:
            base: dict[str, Any] = {"phantom": str(ph_path.resolve())}
            if "geometry" in declared:
                geo = out / "geometry" / f"{ph_path.stem}-seed{seed}.yaml"
                measured = measure_phantom(ph, error_mm=geometry_error_mm, seed=seed)
                geo.write_text(yaml.safe_dump(measured.to_yaml_data(), sort_keys=False), encoding="utf-8")
                base["geometry"] = str(geo.resolve())
            if "seed" in declared:
                base["seed"] = seed
            if "region_mm" in declared and margin_mm is not None:
                w, h = ph.size_mm
                base["region_mm"] = [margin_mm, margin_mm, round(w - margin_mm, 3), round(h - margin_mm, 3)]
            if "contact_z_mm" in declared:
                top = float(np.nanmax(ph.thickness(np.linspace(0, ph.size_mm[0], 25)[:, None],
                                                   np.linspace(0, ph.size_mm[1], 25)[None, :])))
                base["contact_z_mm"] = round(top + 1.0, 3)
            for i, combo in enumerate(combos):
                rid = f"{ph_path.stem}-s{seed}" + (f"-a{i}" if len(combos) > 1 else "")
                specs.append(RunSpec(rid, ph_path, seed, combo, {**base, **combo}, out / "runs" / rid))
    return specs
