"""The wheel's build step (``[tool.setuptools.cmdclass]`` in pyproject.toml): after the
modules are copied into the build folder, the kernels of the shipped families are compiled
there and shipped in the package (``kanagen/kernels/<digest>``, :mod:`kanagen.precompile`),
so that a fit's first use loads them instead of compiling them (~40 s). Not in an editable
install (its kernels are compiled at first use, into the user's cache), nor with
``KANAGEN_PRECOMPILE=0``; a failure leaves the wheel without kernels and says so."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from setuptools.command.build_py import build_py as _build_py


class build_py(_build_py):  # noqa: N801 - setuptools' command name
    def run(self):
        super().run()
        kernels = Path(self.build_lib).resolve() / "kanagen" / "kernels"
        shutil.rmtree(kernels, ignore_errors=True)  # an earlier build's, in build/lib
        if getattr(self, "editable_mode", False) or \
                os.environ.get("KANAGEN_PRECOMPILE", "1").strip() == "0":
            return
        lib = kernels.parent.parent
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [str(lib), *filter(None, [os.environ.get("PYTHONPATH")])]),
            KANAGEN_BACKEND="numpy")  # the kernels are the same on every backend
        print("compiling the shipped families' kernels (kanagen.precompile, ~1-2 minutes)",
              flush=True)
        try:
            done = subprocess.run([sys.executable, "-m", "kanagen.precompile", str(kernels)],
                                  env=env, cwd=lib, check=False, timeout=3600).returncode
        except (OSError, subprocess.SubprocessError) as exc:
            done = exc
        if done != 0:
            shutil.rmtree(kernels, ignore_errors=True)
            self.warn(f"kanagen: the kernels could not be compiled while building ({done}); "
                      "they will be compiled at first use")
