"""AnySkin: the Head-On helmet's magnetic skins (SPEC 2): point-dipole skins over magnetometer crosses,
a walking head pushing a force plate, and the causal contact pipeline."""
