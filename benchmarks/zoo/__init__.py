"""Independent MEMS-gyroscope calibration-rig log simulator ("effect zoo").

Written from the log contract (shared/spec/log-format.md) and the physics papers only,
without reading gyrocal's own simulator, terms, tests or docs.  See README.md.
"""
