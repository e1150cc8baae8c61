"""Young's modulus of a rubber from its indentation hardness.

Gent's relation [Gent1958]_ between the Shore A durometer reading ``S`` and the small-strain
Young's modulus ``E`` of a rubber, in the form given with ASTM D2240 [ASTM-D2240]_:

    E = 0.0981 (56 + 7.62336 S) / (0.137505 (254 - 2.54 S))      [MPa]

The relation is derived for 40 <= S <= 100 (Shore A) [Gent1958]_; below 40 it extrapolates the
indentation theory of an elastic half-space and is a rough estimate (soft silicones such as
Shore 10A). It does not apply to Shore 00 readings.

For Shore 00 materials we use the manufacturer's 100 % tensile modulus instead and convert it with
the neo-Hookean uniaxial law (:func:`young_modulus_from_modulus_100`).

References
----------
.. [Gent1958] A. N. Gent, "On the relation between indentation hardness and Young's modulus",
   Transactions of the Institution of the Rubber Industry 34 (1958) 46-57.
.. [ASTM-D2240] ASTM D2240-15, "Standard Test Method for Rubber Property - Durometer Hardness".
"""

from __future__ import annotations

import numpy as np

__all__ = ["young_modulus_gent_pa", "young_modulus_from_modulus_100"]


def young_modulus_gent_pa(shore_a):
    """Young's modulus (Pa) from a Shore A hardness by Gent's relation.

    shore_a: scalar or array in [0, 100). Returns E in Pa, same shape.
    """
    s = np.asarray(shore_a, dtype=float)
    if np.any(~np.isfinite(s)) or np.any(s < 0) or np.any(s >= 100):
        raise ValueError(f"shore_a = {shore_a}: must be finite and within [0, 100)")
    e_mpa = 0.0981 * (56.0 + 7.62336 * s) / (0.137505 * (254.0 - 2.54 * s))
    return e_mpa * 1e6


def young_modulus_from_modulus_100(modulus_100_pa):
    """Young's modulus (Pa) from a nominal tensile stress at 100 % elongation (Pa).

    Incompressible neo-Hookean solid in uniaxial tension: nominal stress
    P = G (lambda - lambda^-2) at stretch lambda = 2, hence G = P / 1.75 and E = 3 G.
    A simplification: real silicones soften or stiffen away from small strain, so this is an
    estimate of the initial modulus, not a fit.
    """
    p = np.asarray(modulus_100_pa, dtype=float)
    if np.any(~np.isfinite(p)) or np.any(p <= 0):
        raise ValueError(f"modulus_100_pa = {modulus_100_pa}: must be finite and > 0")
    stretch = 2.0
    shear_modulus = p / (stretch - stretch**-2)
    return 3.0 * shear_modulus
