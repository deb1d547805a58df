"""Phantom files (the simulated world) and their ground truth.

File format (a contract other tools write; docs/physics.md and DESIGN.md): units mm, kPa, N/mm;
origin at one corner of the phantom footprint, z up, table at z = 0, so the surface height is the
local thickness. Unknown keys are errors; the optional keys ``name`` and ``description`` (free
text) are the only additions to DESIGN.md's list.

Profile of a domed top ``thickness_mm: {center: C, edge: E}``: along y only (as the paper's
Fig. 12 phantom), a parabola t(y) = E + (C - E) * (1 - (2y/Ly - 1)^2): C on the centre line
y = Ly/2, E at y = 0 and y = Ly, constant along x. Outside the footprint the thickness is 0 (bare
table) and material properties are nan.

An inclusion is a vertical cylinder: radius_mm around center_mm, its top depth_mm below the
local surface (so it follows a domed top), height_mm tall or down to the table. Where inclusions
overlap, the later one in the file wins. The buried-inclusion response felt by an indenter
(``effective_modulus``) is the stress-bulb model documented in docs/physics.md.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, ClassVar

import msgspec
import numpy as np
import numpy.typing as npt

from models._arrays import ArrayLike, FloatArray
from models._arrays import as_f64 as _f64
from models._arrays import scalar_or_array as _out
from yamlstruct import Source, convert
from yamlstruct.convert import kind, label
from yamlstruct.source import Path_

_Pos = Annotated[float, msgspec.Meta(gt=0)]
_NonNeg = Annotated[float, msgspec.Meta(ge=0)]

# Defaults of the contact models behind effective_modulus / spring_constant (docs/physics.md).
DEFAULT_CONTACT_RADIUS_MM = 2.0  # flat-punch radius of one camera-probe indenter tip
MIN_CONTACT_FRACTION = 0.05  # contact radius floor, as a fraction of r, for grazing contact
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(24)


class PhantomError(ValueError):
    """A phantom file or mapping is invalid; the message reads ``file:line:col: key.path: what is wrong``."""


class DomedThickness(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Thickness (mm) on the centre line y = Ly/2 and at the y edges of a domed top."""

    center: _Pos
    edge: _Pos


class Inclusion(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A stiff (or soft) vertical cylinder inside the phantom; exactly one material key is given."""

    center_mm: tuple[float, float]
    radius_mm: _Pos
    depth_mm: _NonNeg
    youngs_modulus_kpa: _Pos | None = None
    spring_constant_n_per_mm: _Pos | None = None
    height_mm: _Pos | None = None


class Noise(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Sensor noise standard deviations the simulator adds (mm, kPa, pixels)."""

    displacement_mm: _NonNeg = 0.005
    pressure_kpa: _NonNeg = 0.01
    pixel: _NonNeg = 0.3


class Phantom(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A validated phantom; build it with ``load_phantom`` or ``parse_phantom``.

    Queries take x, y (mm) as floats or broadcastable arrays and return a float for scalar input.
    """

    size_mm: tuple[_Pos, _Pos]
    thickness_mm: _Pos | DomedThickness
    youngs_modulus_kpa: _Pos | None = None
    spring_constant_n_per_mm: _Pos | None = None
    poisson_ratio: Annotated[float, msgspec.Meta(ge=0, le=0.5)] = 0.5
    inclusions: tuple[Inclusion, ...] = ()
    noise: Noise = msgspec.field(default_factory=Noise)
    name: str = ""
    description: str = ""

    @property
    def is_spring_sample(self) -> bool:
        """True for a sample of springs (paper 2, Table I) rather than tissue."""
        return self.spring_constant_n_per_mm is not None

    # ------------------------------------------------------------------ geometry

    def _inside(self, x: FloatArray, y: FloatArray) -> npt.NDArray[np.bool_]:
        lx, ly = self.size_mm
        inside: npt.NDArray[np.bool_] = (x >= 0) & (x <= lx) & (y >= 0) & (y <= ly)
        return inside

    def thickness(self, x: ArrayLike, y: ArrayLike) -> ArrayLike:
        """Local thickness (mm) at (x, y); 0 outside the footprint."""
        xa, ya = np.broadcast_arrays(_f64(x), _f64(y))
        t = self.thickness_mm
        if isinstance(t, DomedThickness):
            u = 2.0 * ya / self.size_mm[1] - 1.0
            prof = t.edge + (t.center - t.edge) * (1.0 - u * u)
        else:
            prof = np.full(xa.shape, float(t))
        return _out(np.where(self._inside(xa, ya), prof, 0.0), x, y)

    def surface_z(self, x: ArrayLike, y: ArrayLike) -> ArrayLike:
        """Height (mm) of the top surface above the table at (x, y): the local thickness."""
        return self.thickness(x, y)

    def inclusion_at(self, x: ArrayLike, y: ArrayLike) -> int | npt.NDArray[np.int64]:
        """Index of the inclusion whose footprint contains (x, y) (the later one if several), else -1."""
        xa, ya = np.broadcast_arrays(_f64(x), _f64(y))
        idx = np.full(xa.shape, -1, dtype=np.int64)
        for i, inc in enumerate(self.inclusions):
            cx, cy = inc.center_mm
            idx[(xa - cx) ** 2 + (ya - cy) ** 2 <= inc.radius_mm**2] = i
        idx[~self._inside(xa, ya)] = -1
        if np.ndim(x) == 0 and np.ndim(y) == 0:
            return int(idx)
        return idx

    # ------------------------------------------------------------------ material

    def _background(self) -> float:
        value = self.spring_constant_n_per_mm if self.is_spring_sample else self.youngs_modulus_kpa
        return float(value)  # type: ignore[arg-type]  # validation guarantees one is set

    def _inclusion_value(self, inc: Inclusion) -> float:
        value = inc.spring_constant_n_per_mm if self.is_spring_sample else inc.youngs_modulus_kpa
        return float(value)  # type: ignore[arg-type]

    def _require_tissue(self, what: str) -> None:
        if self.is_spring_sample:
            raise ValueError(
                f"phantom {self.name or '(unnamed)'}: {what}() needs a tissue phantom "
                "(youngs_modulus_kpa); this is a spring sample, use spring_constant()"
            )

    def youngs_modulus(self, x: ArrayLike, y: ArrayLike, depth: ArrayLike = 0.0) -> ArrayLike:
        """Ground-truth Young's modulus (kPa) at (x, y) and depth (mm) below the local surface.

        nan outside the footprint, above the surface (depth < 0) or below the table.
        """
        self._require_tissue("youngs_modulus")
        xa, ya, da = np.broadcast_arrays(_f64(x), _f64(y), _f64(depth))
        t = _f64(self.thickness(xa, ya))
        e = np.full(xa.shape, self._background())
        for inc in self.inclusions:
            cx, cy = inc.center_mm
            bottom = t if inc.height_mm is None else np.minimum(inc.depth_mm + inc.height_mm, t)
            hit = (
                ((xa - cx) ** 2 + (ya - cy) ** 2 <= inc.radius_mm**2)
                & (da >= inc.depth_mm)
                & (da <= bottom)
            )
            e[hit] = self._inclusion_value(inc)
        e[~self._inside(xa, ya) | (da < 0) | (da > t)] = np.nan
        return _out(e, x, y, depth)

    def _bulb_fractions(
        self, x: FloatArray, y: FloatArray, c: FloatArray, d: FloatArray
    ) -> FloatArray:
        """Fraction phi_i (..., n_inclusions) of the indenter's stress bulb inside each inclusion.

        Depth weight: on-axis vertical stress under a uniformly loaded disc of radius c,
        g(z) ~ 1 - z^3 / (z^2 + c^2)^1.5, with z measured down from the indenter tip (which sits d
        below the surface). Lateral weight at depth z: an isotropic Gaussian of per-axis variance
        c^2/4 + z^2 (the second moment of the disc convolved with Boussinesq's point-load stress).
        The fraction of that Gaussian inside a disc of radius R at lateral distance l is a
        non-central chi-square CDF with 2 degrees of freedom. Normalised by the bulb inside the
        tissue (z up to thickness - d) so the table does not count: its effect is the thickness
        correction of the contact law.
        """
        if not self.inclusions:
            return np.zeros((*x.shape, 0))
        # One axis per inclusion (-2) and per quadrature node (-1): a single pass of numpy calls.
        cx, cy, radius, top, height = _inclusion_table(self.inclusions)
        t = _f64(self.thickness(x, y))[..., None, None]
        z_max = np.maximum(t - d[..., None, None], 1e-9)
        cc = c[..., None, None]
        lat2 = (x[..., None, None] - cx) ** 2 + (y[..., None, None] - cy) ** 2
        z0 = np.clip(top - d[..., None, None], 0.0, z_max)
        z1 = np.clip(np.minimum(top + height, t) - d[..., None, None], z0, z_max)
        half = 0.5 * (z1 - z0)
        z = 0.5 * (z0 + z1) + half * _GL_NODES
        dens = (1.0 - z**3 / (z * z + cc * cc) ** 1.5) / (2.0 * cc)
        var = cc * cc / 4.0 + z * z
        # imported here: scipy.special costs every importer ~0.1 s, and few call this
        from scipy.special import chndtr

        lateral = chndtr(radius**2 / var, 2.0, lat2 / var)
        integral = half[..., 0] * np.sum(_GL_WEIGHTS * dens * lateral, axis=-1)
        norm = _bulb_cdf(z_max[..., 0], cc[..., 0])
        with np.errstate(divide="ignore", invalid="ignore"):  # no tissue under the tip: phi = 0
            phi = np.where(norm > 1e-12, integral / norm, 0.0)
        total = phi.sum(-1, keepdims=True)
        # Overlapping inclusions could count one volume twice; never let the sum exceed 1.
        out: FloatArray = np.where(total > 1.0, phi / np.maximum(total, 1e-300), phi)
        return out

    def _mixed(self, x: FloatArray, y: FloatArray, c: FloatArray, d: FloatArray) -> FloatArray:
        """Background blended linearly with each inclusion by its bulb fraction; nan off the phantom."""
        base = self._background()
        value = np.full(x.shape, base)
        if self.inclusions:
            phi = self._bulb_fractions(x, y, c, d)
            values = np.array([self._inclusion_value(inc) for inc in self.inclusions])
            value = base + np.sum(phi * (values - base), axis=-1)
        out: FloatArray = np.where(self._inside(x, y), value, np.nan)
        return out

    def effective_modulus(
        self, x: ArrayLike, y: ArrayLike, indenter_radius_mm: float, depth_mm: ArrayLike
    ) -> ArrayLike:
        """Young's modulus (kPa) felt by a sphere of radius r (mm) indenting depth_mm at (x, y).

        Contact radius c = sqrt(r d) (eq. 5, floored at ``MIN_CONTACT_FRACTION * r``);
        E_eff = E_bg + sum_i phi_i (E_i - E_bg) with phi_i from ``_bulb_fractions``. E_eff falls
        with the inclusion's depth, lateral distance, smaller radius and lower stiffness ratio,
        and is radially symmetric about an inclusion's axis on a flat phantom.
        """
        self._require_tissue("effective_modulus")
        if not (math.isfinite(indenter_radius_mm) and indenter_radius_mm > 0):
            raise ValueError(
                f"effective_modulus: indenter_radius_mm must be > 0, got {indenter_radius_mm!r}"
            )
        xa, ya, da = np.broadcast_arrays(_f64(x), _f64(y), _f64(depth_mm))
        c = np.maximum(
            np.sqrt(indenter_radius_mm * np.clip(da, 0.0, None)),
            MIN_CONTACT_FRACTION * indenter_radius_mm,
        )
        return _out(self._mixed(xa, ya, c, np.clip(da, 0.0, None)), x, y, depth_mm)

    def spring_constant(
        self,
        x: ArrayLike,
        y: ArrayLike,
        contact_radius_mm: float = DEFAULT_CONTACT_RADIUS_MM,
        depth_mm: ArrayLike = 0.0,
    ) -> ArrayLike:
        """Local stiffness K_t (N/mm) felt by one small indenter at (x, y).

        Spring sample: the file's spring constant (an inclusion's inside its footprint). Tissue:
        a rigid flat punch of radius a = contact_radius_mm on an elastic half-space,
        K_t = 2 a E_eff / (1 - nu^2), with E_eff the stress-bulb modulus for contact radius a at
        depth_mm (kPa converted to N/mm^2). 26.4 kPa and a = 2 mm give 0.14 N/mm.
        """
        xa, ya, da = np.broadcast_arrays(_f64(x), _f64(y), _f64(depth_mm))
        if self.is_spring_sample:
            k = np.full(xa.shape, self._background())
            idx = np.asarray(self.inclusion_at(xa, ya))
            for i, inc in enumerate(self.inclusions):
                k[idx == i] = self._inclusion_value(inc)
            k[~self._inside(xa, ya)] = np.nan
            return _out(k, x, y, depth_mm)
        if not (math.isfinite(contact_radius_mm) and contact_radius_mm > 0):
            raise ValueError(
                f"spring_constant: contact_radius_mm must be > 0, got {contact_radius_mm!r}"
            )
        c = np.full(xa.shape, float(contact_radius_mm))
        e_kpa = self._mixed(xa, ya, c, np.clip(da, 0.0, None))
        k = 2.0 * contact_radius_mm * e_kpa * 1e-3 / (1.0 - self.poisson_ratio**2)
        return _out(k, x, y, depth_mm)


def _inclusion_table(incs: tuple[Inclusion, ...]) -> tuple[FloatArray, ...]:
    """Columns (n, 1) of centre x, centre y, radius, top depth and height (inf: to the table)."""
    rows = np.array(
        [
            (i.center_mm[0], i.center_mm[1], i.radius_mm, i.depth_mm, i.height_mm or np.inf)
            for i in incs
        ]
    )
    return tuple(rows[:, k : k + 1] for k in range(5))


def _bulb_cdf(z: FloatArray, c: FloatArray) -> FloatArray:
    """Integral of the normalised on-axis stress density from 0 to z (-> 1 as z -> inf)."""
    q = np.sqrt(z * z + c * c)
    out: FloatArray = (z + 2.0 * c - q - c * c / q) / (2.0 * c)
    return out


# ---------------------------------------------------------------------- loading and validation


class _PhantomSource(Source):
    error_type: ClassVar[type[Exception]] = PhantomError
    document: ClassVar[str] = "the phantom"


def _check_finite(obj: Any, path: Path_, src: Source) -> None:
    if isinstance(obj, float) and not math.isfinite(obj):
        raise src.error(path, f"{label(path, src.document)}: must be a finite number, got {obj}")
    if isinstance(obj, msgspec.Struct):
        for f in obj.__struct_fields__:
            _check_finite(getattr(obj, f), (*path, f), src)
    elif isinstance(obj, tuple):
        for i, item in enumerate(obj):
            _check_finite(item, (*path, i), src)


def _validate(ph: Phantom, src: Source) -> None:
    """What the schema cannot say: one material, inclusions of that material, inside the footprint, below the top."""
    _check_finite(ph, (), src)
    tissue, spring = ph.youngs_modulus_kpa is not None, ph.spring_constant_n_per_mm is not None
    if tissue == spring:
        raise src.error(("youngs_modulus_kpa",), "youngs_modulus_kpa: give exactly one of youngs_modulus_kpa (tissue) or "
                            "spring_constant_n_per_mm (spring sample)" + (", got both" if tissue else ", got neither"))
    own, other = (("spring_constant_n_per_mm", "youngs_modulus_kpa") if spring
                  else ("youngs_modulus_kpa", "spring_constant_n_per_mm"))
    lx, ly = ph.size_mm
    for i, inc in enumerate(ph.inclusions):
        at: Path_ = ("inclusions", i)
        if getattr(inc, other) is not None:
            raise src.error((*at, other), f"{label((*at, other), '')}: not allowed in a phantom that uses {own}")
        if getattr(inc, own) is None:
            raise src.error(at, f"{label((*at, own), '')}: required key missing")
        cx, cy = inc.center_mm
        if not (0 <= cx <= lx and 0 <= cy <= ly):
            raise src.error((*at, "center_mm"), f"{label((*at, 'center_mm'), '')}: must lie inside the footprint "
                                                f"[0, {lx}] x [0, {ly}] mm, got [{cx}, {cy}]")
        local = float(ph.thickness(cx, cy))
        if inc.depth_mm >= local:
            raise src.error((*at, "depth_mm"), f"{label((*at, 'depth_mm'), '')}: must be less than the local "
                                               f"thickness {local:.1f} mm, got {inc.depth_mm}")


def _phantom(src: Source) -> Phantom:
    if not isinstance(src.data, dict):
        raise src.error((), f"expected a mapping at the top level, got {kind(src.data)}")
    ph: Phantom = convert(src, src.data, Phantom)
    _validate(ph, src)
    return ph


def parse_phantom(data: Any, source: str = "<phantom>") -> Phantom:
    """Validate a decoded phantom mapping (e.g. from :mod:`models.phantom_gen`); errors name ``source`` and the key."""
    return _phantom(_PhantomSource(path=Path(source), name=source, data=data))


def load_phantom(path: str | Path) -> Phantom:
    """Read and validate a phantom YAML file through :mod:`yamlstruct` (the project's one YAML loader).

    Raises:
        PhantomError: ``file:line:col: key.path: what is wrong`` (unreadable file, malformed YAML, a key the format
            does not have, a wrong type or bound, or a physically impossible phantom).
    """
    return _phantom(_PhantomSource.read(Path(path)))
