"""``mlsim sweep``: compare sensor designs before moulding (variants, metrics, the driver, the report)."""

from mlsim.sweep.run import sweep
from mlsim.sweep.variants import parse_vary, variants

__all__ = ["sweep", "parse_vary", "variants"]
