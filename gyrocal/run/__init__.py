"""Running it: the command line, the workflow's stages, the job guard, the BLAS thread count.
May import: every other folder of gyrocal."""
