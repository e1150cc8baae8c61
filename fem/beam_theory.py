"""Cantilever beam references for verification: Timoshenko deflection and bending stress.

A prismatic cantilever of length L, clamped at z = 0 and loaded by a transverse force F at its free
end, has the tip deflection [Timoshenko1921]_

    delta = F L^3 / (3 E I) + F L / (kappa G A)

(bending plus shear), with the shear coefficient of a solid circular section
kappa = 6 (1 + nu) / (7 + 6 nu), which makes this formula agree with Saint-Venant's exact flexure
solution [Cowper1966]_. The bending stress at height z on the outer fibre (distance c from the
neutral axis) is sigma = M c / I = F (L - z) c / I; for a circle of radius r, 4 F (L - z) / (pi r^3).

The clamp of beam theory holds the root section plane and perpendicular to the axis with zero mean
deflection, but lets it contract in its own plane. A 3-D model that also pins every in-plane
displacement of the root face is stiffer, the more so the shorter the beam and the closer nu is to
1/2 (see tests/test_beam.py).

References
----------
.. [Timoshenko1921] S. P. Timoshenko, "On the correction for shear of the differential equation for
   transverse vibrations of prismatic bars", Philosophical Magazine 41 (1921) 744-746.
.. [Cowper1966] G. R. Cowper, "The shear coefficient in Timoshenko's beam theory", Journal of
   Applied Mechanics 33 (1966) 335-340, table 1 (circle).
"""

from __future__ import annotations

import math

__all__ = ["circular_shear_coefficient", "timoshenko_tip_deflection_m", "bending_stress_pa"]


def circular_shear_coefficient(poisson_ratio: float) -> float:
    """Cowper's shear coefficient of a solid circular section."""
    return 6.0 * (1.0 + poisson_ratio) / (7.0 + 6.0 * poisson_ratio)


def timoshenko_tip_deflection_m(force_n: float, length_m: float, radius_m: float, young_modulus_pa: float, poisson_ratio: float) -> float:
    """Tip deflection (m) of a circular cantilever under an end force (bending + shear)."""
    area = math.pi * radius_m**2
    inertia = math.pi * radius_m**4 / 4.0
    shear_modulus = young_modulus_pa / (2.0 * (1.0 + poisson_ratio))
    bending = force_n * length_m**3 / (3.0 * young_modulus_pa * inertia)
    shear = force_n * length_m / (circular_shear_coefficient(poisson_ratio) * shear_modulus * area)
    return bending + shear


def bending_stress_pa(force_n: float, length_m: float, radius_m: float, z_m: float) -> float:
    """Outer-fibre bending stress (Pa) at height z of a circular cantilever: 4 F (L - z) / (pi r^3)."""
    return 4.0 * force_n * (length_m - z_m) / (math.pi * radius_m**3)
