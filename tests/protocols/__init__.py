"""The protocols: turntable segmentation, servo, sweep, hand rotation (Ferraris), static logs."""
