"""The fleet: its summary and page, end of line, drift audits, outliers, limits, manifests.
May import: io, terms, fit, calibration, report, protocols."""
