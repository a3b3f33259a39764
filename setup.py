# Only the optional compiled kernels are declared here (setuptools' pyproject table for
# extensions is still experimental); everything else is in pyproject.toml. Where no C
# compiler is at hand the build skips them and gyrocal uses their numpy paths.
from setuptools import Extension, setup

KERNELS = {
    "gyrocal.io._blockstats": "gyrocal/io/_blockstats.c",  # the read's block statistics
    "gyrocal.fit._kernels": "gyrocal/fit/_kernels.c",  # Allan sums, the wander's Cholesky
}

setup(ext_modules=[Extension(name, [source], optional=True, extra_compile_args=["-O3"])
                   for name, source in KERNELS.items()])
