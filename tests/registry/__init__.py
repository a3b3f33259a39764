"""The calibration registry: its SQLite and PostgreSQL back ends, the latter on a real server (tests/pg.py)."""
