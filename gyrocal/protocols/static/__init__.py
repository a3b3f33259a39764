"""A static log: the unit lies still at a steady temperature (a bench's noise recording, a
host's capture of a consumer IMU), read as the sweep's windows without a temperature span.
Its noise characterisation is the point; its calibration is the bias at that temperature."""
