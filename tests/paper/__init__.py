"""The seed papers' tables regenerated."""
