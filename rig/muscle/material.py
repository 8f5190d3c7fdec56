"""Tissue materials in physical units: what a part of the body is made of, as a finite-element solver takes it.

A Material is a small-strain isotropic solid: Young's modulus E (Pa), Poisson's ratio nu, density rho (kg/m^3)
and a damping ratio zeta (of the part's fundamental mode, dimensionless), as Ziva VFX and Houdini's FEM take a
tissue. The particles' goal springs follow from a part's material and its real size by a rule calibrated
against the volumetric reference (sim/jiggle/materials.py); the FEM path (sim/fem) takes them as they are.

Defaults from the soft-tissue literature (small strain, the rates of a jiggle: a few to tens of Hz):

- Fat (subcutaneous adipose tissue): E = 3 kPa, nu = 0.49, rho = 920 kg/m^3. Samani, Zubovits & Plewes 2007
  (Phys Med Biol 52:1565) measured breast fat at 3.25 +- 0.91 kPa; Comley & Fleck 2010 (J Biomech 43:1823)
  found porcine adipose 1-2 kPa at low rates, stiffening with rate; Alkhouli et al. 2013 (Am J Physiol Endocrinol
  Metab 305:E1427) human subcutaneous fat 2-4 kPa. Density 900-950 kg/m^3 (Farvid et al. 2005). Adipose is
  nearly incompressible (nu 0.49-0.499); 0.49 keeps an explicit solve well conditioned.
- Relaxed skeletal muscle: E = 15 kPa, nu = 0.49, rho = 1060 kg/m^3. Shear-wave elastography of relaxed limb
  muscle gives shear moduli of 3-10 kPa across the fibres (Eby et al. 2013, J Biomech 46:2381; Lacourpaille et
  al. 2012, Physiol Meas 33:N19), E = 3 G = 9-30 kPa; indentation of passive muscle 10-20 kPa (Ogneva et al.
  2010). Density 1060 kg/m^3 (Mendez & Keys 1960).
- Damping: relaxed muscle rings with a log decrement of 1.0-1.6 (zeta 0.16-0.25, MyotonPRO reference ranges) and
  activity damps the soft-tissue resonance further (Wakeling, Nigg & Rozitis 2002, J Appl Physiol 93:1093), so
  muscle 0.5 as the templates had; fat's wobble lasts longer on a landing: 0.3.

Names parse as "fat", "muscle", or "E=...,nu=...,rho=...,zeta=..." (any omitted key taken from `base`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from jiggle.rig.base.errors import InputError


@dataclass(frozen=True)
class Material:
    """An isotropic tissue. youngs_pa : E > 0, Pa. poisson : nu in [0, 0.5). density : rho > 0, kg/m^3.
    damping_ratio : zeta >= 0 of the part's fundamental mode. name : what it was called ("fat", "muscle", or
    "custom")."""

    youngs_pa: float
    poisson: float
    density: float
    damping_ratio: float
    name: str = "custom"

    def __post_init__(self):
        checks = (("youngs_pa", self.youngs_pa > 0, "> 0 Pa"), ("poisson", 0.0 <= self.poisson < 0.5, "in [0, 0.5)"),
                  ("density", self.density > 0, "> 0 kg/m^3"), ("damping_ratio", self.damping_ratio >= 0, ">= 0"))
        for f, ok, expect in checks:
            v = getattr(self, f)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or not ok:
                raise InputError(f"material {self.name!r}: {f} must be {expect}, got {v!r}", field=f)

    @property
    def shear_pa(self) -> float:
        """mu = E / (2 (1 + nu)), Pa: the shear modulus (the second Lame parameter), what a wobble shears."""
        return self.youngs_pa / (2.0 * (1.0 + self.poisson))

    @property
    def lame_pa(self) -> float:
        """lambda = E nu / ((1 + nu)(1 - 2 nu)), Pa."""
        return self.youngs_pa * self.poisson / ((1.0 + self.poisson) * (1.0 - 2.0 * self.poisson))

    @property
    def shear_speed(self) -> float:
        """sqrt(mu / rho), m/s: how fast a shear wave crosses the tissue; a part's wobble frequency goes as it
        over the part's size."""
        return math.sqrt(self.shear_pa / self.density)

    def to_json(self) -> dict:
        return {"name": self.name, "youngs_pa": self.youngs_pa, "poisson": self.poisson, "density": self.density,
                "damping_ratio": self.damping_ratio}


FAT = Material(youngs_pa=3.0e3, poisson=0.49, density=920.0, damping_ratio=0.3, name="fat")
MUSCLE = Material(youngs_pa=15.0e3, poisson=0.49, density=1060.0, damping_ratio=0.5, name="muscle")
MATERIALS = {"fat": FAT, "muscle": MUSCLE}
"""The named materials; a part of kind K (rig.muscle.model kinds "muscle", "fat") defaults to MATERIALS[K]."""
KEYS = {"E": "youngs_pa", "nu": "poisson", "rho": "density", "zeta": "damping_ratio"}
"""The keys of a material written out: "E=3000,nu=0.49,rho=920,zeta=0.3" (E in Pa, or with a kPa / MPa suffix)."""


def material_for(kind: str) -> Material:
    """The default material of a part of `kind` ("fat", anything else muscle)."""
    return MATERIALS.get(kind, MUSCLE)


def parse_material(text, base: Material | None = None, where: str = "--material") -> Material:
    """A Material from "fat", "muscle", a Material, a mapping {E, nu, rho, zeta} or "E=...,nu=...,rho=...,zeta=..."
    (keys omitted come from `base`, muscle when None; E takes Pa or a kPa / MPa suffix); InputError naming `where`."""
    if isinstance(text, Material):
        return text
    base = base or MUSCLE
    if isinstance(text, dict):
        items = list(text.items())
    else:
        s = str(text).strip()
        if s.lower() in MATERIALS:
            return MATERIALS[s.lower()]
        items = []
        for part in filter(None, (p.strip() for p in s.split(","))):
            if "=" not in part:
                raise InputError(f"{where}: expected fat, muscle or E=...,nu=...,rho=...,zeta=..., got {s!r}",
                                 field="material")
            k, v = (x.strip() for x in part.split("=", 1))
            items.append((k, v))
        if not items:
            raise InputError(f"{where}: expected fat, muscle or E=...,nu=...,rho=...,zeta=..., got {s!r}",
                             field="material")
    values = {}
    for k, v in items:
        if k not in KEYS:
            raise InputError(f"{where}: unknown material key {k!r}; expected one of {', '.join(KEYS)}", field="material")
        values[KEYS[k]] = _number(v, k, where)
    return replace(base, name="custom", **values)


def _number(v, key: str, where: str) -> float:
    scale = 1.0
    if isinstance(v, str):
        s = v.strip()
        for suffix, f in (("MPa", 1e6), ("kPa", 1e3), ("Pa", 1.0)):
            if key == "E" and s.endswith(suffix):
                s, scale = s[: -len(suffix)].strip(), f
                break
        v = s
    try:
        x = float(v) * scale
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key} must be a number, got {v!r}", field="material") from None
    if not math.isfinite(x):
        raise InputError(f"{where}: {key} is NaN or inf", field="material")
    return x


__all__ = ["Material", "FAT", "MUSCLE", "MATERIALS", "KEYS", "material_for", "parse_material"]
