"""
Rubber (silicone) constants for hyperelastic shells, and the balloon law they are checked on.

The theory, the kinematic assumption of the lumped model's membrane and the limits are in
``docs/theory/hyperelastic.md``.

``SILICONES``: neo-Hookean shear moduli of common casting silicones. Each is a one-point fit to
the manufacturer's "100 % modulus" (the engineering stress at 100 % strain in uniaxial tension,
ASTM D412, Smooth-On technical bulletins): an incompressible neo-Hookean strip stretched to
lambda = 2 carries the engineering stress mu (lambda - 1/lambda^2) = 1.75 mu, so
mu = sigma_100 / 1.75. The 100 % moduli were read from a third-party table that quotes the
bulletins (the bulletins themselves were not opened when this table was written; check them
before relying on a value). A one-point fit says nothing about the stiffening of these silicones
at large stretch: the neo-Hookean law is the softest reading of each at large stretch. No
Mooney-Rivlin (C1, C2) pair could be verified for these silicones, so none is tabled (give
``material.mooney_rivlin_c1_pa``/``_c2_pa`` explicitly), nor Sylgard 184 (no verified fit).

The scene rules the lumped and the shell models share (one place for each): which material keys
belong to which law (`refuse_keys_of_other_laws`) and how a neo-Hookean shear modulus is given
(`neo_hookean_shear_modulus_pa`: a tabled ``silicone`` or ``shear_modulus_pa``, exactly one).
The shell's law is in ``docs/theory/shell_rubber.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from pulsejet_sim.core.model_io import ModelError

PSI_PA = 6894.757293168361  # Pa per psi (lbf/in^2)
NEO_HOOKEAN_UNIAXIAL_AT_100_PERCENT = 2.0 - 1.0 / 4.0  # lambda - 1/lambda^2 at lambda = 2


@dataclass(frozen=True)
class Silicone:
    """A tabled silicone: its neo-Hookean shear modulus and where it comes from."""

    name: str
    modulus_100_percent_pa: float  # engineering stress at 100 % uniaxial strain, Pa
    source: str

    @property
    def shear_modulus_pa(self) -> float:
        """Neo-Hookean mu from the 100 % modulus (one-point fit at lambda = 2), Pa."""
        return self.modulus_100_percent_pa / NEO_HOOKEAN_UNIAXIAL_AT_100_PERCENT


_BULLETIN = (
    'Smooth-On technical bulletin, "100% Modulus" {psi} psi (ASTM D412), as quoted by a '
    'third-party table of the bulletins; neo-Hookean mu = sigma_100 / 1.75'
)

SILICONES = {
    name: Silicone(name, psi * PSI_PA, _BULLETIN.format(psi=psi))
    for name, psi in (
        ('ecoflex_00_30', 10.0),
        ('ecoflex_00_50', 12.0),
        ('dragon_skin_10', 22.0),
        ('dragon_skin_20', 49.0),
        ('dragon_skin_30', 86.0),
    )
}


#: the values of ``material.silicone``: none, or a tabled silicone
SILICONE_CHOICES = ('none', *SILICONES)


def refuse_keys_of_other_laws(
    given: Mapping[str, Any], law: str, law_keys: Mapping[str, tuple[str, ...]]
) -> None:
    """
    Refuse a material key that belongs to another law than ``law`` (never ignore it).

    ``law_keys`` maps each law to the keys it takes; ``silicone: none`` counts as not given.
    Raises ModelError naming the key, the law and the keys of every law.
    """
    for key in sorted({k for keys in law_keys.values() for k in keys}):
        if key in given and key not in law_keys[law]:
            if key == 'silicone' and given[key] == 'none':
                continue
            takes = ', '.join(f'{name}: {", ".join(keys)}' for name, keys in law_keys.items())
            raise ModelError(
                f'material.{key}: given with material.law {law!r}, which does not use it; '
                f'allowed: the keys of the law ({takes})'
            )


def neo_hookean_shear_modulus_pa(
    given: Mapping[str, Any], silicone: str, shear_modulus_pa: float
) -> float:
    """
    Return the neo-Hookean shear modulus mu, Pa: the tabled silicone's, or shear_modulus_pa.

    ``given`` is the scene's material section as written (to tell a default from a value),
    ``silicone`` and ``shear_modulus_pa`` the checked values. Exactly one of the two must be
    given; otherwise ModelError names both and what is allowed.
    """
    tabled = silicone != 'none'
    if tabled == ('shear_modulus_pa' in given):
        raise ModelError(
            f'material.law: neo_hookean needs exactly one of material.silicone (one of '
            f'{", ".join(SILICONES)}) or material.shear_modulus_pa (Pa); given '
            f'{"both" if tabled else "neither"}'
        )
    return SILICONES[silicone].shear_modulus_pa if tabled else float(shear_modulus_pa)


def spherical_balloon_pressure_pa(
    stretch: float, c1_pa: float, c2_pa: float, thickness_m: float, radius_m: float
) -> float:
    """
    Return the inflation pressure of a thin Mooney-Rivlin spherical membrane, Pa.

    Reference radius R0 and thickness H0, stretch lambda = r / R0 (both in-plane stretches),
    W = C1 (I1 - 3) + C2 (I2 - 3): p = 4 (H0/R0) (C1 (1/lambda - 1/lambda^7) + C2 (lambda -
    1/lambda^5)). Neo-Hookean (C2 = 0, mu = 2 C1): p = 2 mu (H0/R0) (1/lambda - 1/lambda^7), whose
    maximum is at lambda = 7^(1/6) (e.g. Ogden, Non-linear Elastic Deformations, 1984; derived in
    docs/theory/hyperelastic.md).
    """
    lam = float(stretch)
    return (
        4.0
        * thickness_m
        / radius_m
        * (c1_pa * (1.0 / lam - lam**-7) + c2_pa * (lam - lam**-5))
    )


NEO_HOOKEAN_BALLOON_PEAK_STRETCH = 7.0 ** (1.0 / 6.0)


def neo_hookean_balloon_peak_pressure_pa(
    shear_modulus_pa: float, thickness_m: float, radius_m: float
) -> float:
    """Return the neo-Hookean balloon's largest pressure (at lambda = 7^(1/6)), Pa."""
    return spherical_balloon_pressure_pa(
        NEO_HOOKEAN_BALLOON_PEAK_STRETCH, 0.5 * shear_modulus_pa, 0.0, thickness_m, radius_m
    )
