"""The one C extension: poisoner/_jpeg_entropy.c, the bit-level JPEG splice (poisoner/jpeg_scan.py).
Everything else about the package is in pyproject.toml. optional: where no C compiler is found the
package is built without it and ppd takes libjpeg-turbo's slower path (tests/test_packaging.py checks
that the wheel CI builds holds it)."""

from setuptools import Extension, setup

setup(ext_modules=[Extension("poisoner._jpeg_entropy", ["poisoner/_jpeg_entropy.c"], optional=True)])
