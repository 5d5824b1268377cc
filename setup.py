"""The C extensions: poisoner/_jpeg_entropy.c, the bit-level JPEG splice (poisoner/jpeg_scan.py), and
poisoner/_scene_filter.c, the scene hint's Gaussian (poisoner/scene.py). Everything else about the
package is in pyproject.toml. Both optional: where no C compiler is found the package is built without
them and ppd takes libjpeg-turbo's slower path and the hint's numpy filter (tests/test_packaging.py
checks that the wheel CI builds holds them)."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension("poisoner._jpeg_entropy", ["poisoner/_jpeg_entropy.c"], optional=True),
        # no fused multiply-add: the filter's sums must round as scipy's do (bit-for-bit test)
        Extension(
            "poisoner._scene_filter", ["poisoner/_scene_filter.c"], optional=True,
            extra_compile_args=["-ffp-contract=off"],
        ),
    ]
)
