"""The diagnosis: what the model lacks, the shapes and fixes it offers, on simulated and independent units."""
