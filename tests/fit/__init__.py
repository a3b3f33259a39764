"""The fit: the model, interpolation across temperature, Allan noise, the noise floor, the wander-aware fit."""
