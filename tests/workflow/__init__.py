"""End-to-end runs: the Snakemake workflow locally, on a cluster profile, on SLURM, from object storage, its faults, and its reports in a browser."""
