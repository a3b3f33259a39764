"""The reports' drawing."""
