"""The ferraris protocol's settings by default (a config's ``protocols.ferraris`` overrides
them key by key); read without importing the protocol's code.

The model is the common 12 parameters at the session's one temperature; the diagnosis tries
only what one temperature and one turn per axis can tell apart: the static faces, gravity
along each axis both ways, separate a g-sensitivity from the bias."""

from ..model import DEFAULT_TERMS

DEFAULTS = {"options": {}, "model": {"terms": list(DEFAULT_TERMS)},
            "diagnosis": {"candidates": ["g_sensitivity"]}}
