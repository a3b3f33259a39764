"""The fit: the model, the noise floor and wander, profiling, the temperature grid, validation.
May import: io, terms."""
