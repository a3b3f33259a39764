# Only the optional block kernel is declared here (setuptools' pyproject table for
# extensions is still experimental); everything else is in pyproject.toml. Where no C
# compiler is at hand the build skips it and gyrocal uses its numpy path.
from setuptools import Extension, setup

setup(ext_modules=[Extension("gyrocal.io._blockstats", ["gyrocal/io/_blockstats.c"],
                             optional=True, extra_compile_args=["-O3"])])
