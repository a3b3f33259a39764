"""Running it: the command line, the Python API, the workflow's stages, the job guard, BLAS threads.
May import: every other folder of gyrocal."""
