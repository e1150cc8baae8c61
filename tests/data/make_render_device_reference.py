"""Regenerate tests/data/render_device_reference.npz: the CPU renders of test_render_cuda.py's
reference scene that the GPU tests compare with (the project's GPU machines have no CPU variant).
Run after a change to the sensor scene or to Mitsuba (test_stored_cpu_reference_is_the_cpu_renderers
fails then):

    PYTHONPATH=.:tests .venv/bin/python tests/data/make_render_device_reference.py
"""

from pathlib import Path

import numpy as np

from test_render_cuda import REFERENCE, reference_renders

if __name__ == "__main__":
    np.savez(REFERENCE, **reference_renders("cpu"))
    print(f"wrote {REFERENCE} ({Path(REFERENCE).stat().st_size} bytes)")
