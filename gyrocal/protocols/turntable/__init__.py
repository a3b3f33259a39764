"""The multi-temperature turntable protocol (seed 000): soaks at set points, constant-rate
holds on several mounts, handling motion between them; segmentation in :mod:`.segment`."""
