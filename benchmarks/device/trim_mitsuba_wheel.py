"""Trim Mitsuba's wheel to what the CUDA render device needs, so that it travels to a GPU machine.

A GPU machine of this project has no registries: mitsuba and drjit travel as wheels, and a call
carries at most 64 MiB. Mitsuba 3.9.1's cp312 wheel is 62.6 MB; this drops the CPU and polarized
variants, the sRGB spectral upsampling table and plugins the sensor scene never loads (volumes,
ellipsoids, curves, sky models), leaving 32 MB with ``cuda_ad_mono``, ``cuda_ad_spectral`` and
``scalar_rgb``. RECORD loses the dropped files' lines. Usage (benchmarks/device/README.md):

    python3 benchmarks/device/trim_mitsuba_wheel.py mitsuba-3.9.1-cp312-*.whl .whl/
"""

from __future__ import annotations

import re
import sys
import zipfile
from pathlib import Path

KEEP_VARIANTS = {"cuda_ad_mono", "cuda_ad_spectral", "scalar_rgb"}
UNUSED = ("data/srgb.coeff", "data/sunsky/", "plugins/volpathmis.so", "plugins/ellipsoids.so", "plugins/ellipsoidsmesh.so",
          "plugins/volpath.so", "plugins/bsplinecurve.so", "plugins/sunsky.so", "plugins/timed_sunsky.so", "plugins/sdfgrid.so",
          "plugins/hair.so", "plugins/measured_polarized.so")
VARIANT_MODULE = re.compile(r"/((?:llvm_ad|cuda_ad|scalar)_[a-z_]+)\.cpython")


def dropped(name: str) -> bool:
    m = VARIANT_MODULE.search(name)
    return bool(m and m.group(1) not in KEEP_VARIANTS) or any(u in name for u in UNUSED)


def trim(src: Path, out_dir: Path) -> Path:
    dst = out_dir / src.name
    out_dir.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zout:
        gone = {i.filename for i in zin.infolist() if dropped(i.filename)}
        for info in zin.infolist():
            if info.filename in gone:
                continue
            data = zin.read(info.filename)
            if info.filename.endswith(".dist-info/RECORD"):
                data = "".join(line + "\n" for line in data.decode().splitlines() if line.split(",")[0] not in gone).encode()
            zout.writestr(info, data, compress_type=zipfile.ZIP_DEFLATED, compresslevel=9)
    print(f"{dst}: {dst.stat().st_size / 2**20:.1f} MiB ({len(gone)} files dropped)")
    return dst


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    trim(Path(sys.argv[1]), Path(sys.argv[2]))
