"""The unit report and what every page is made of: the Jinja environment, templates, figures.
May import: io, fit, calibration."""
