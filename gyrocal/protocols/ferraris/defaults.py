"""The ferraris protocol's settings by default (a config's ``protocols.ferraris`` overrides
them key by key); read without importing the protocol's code. Its options are the config
schema's (``$defs/ferraris_options``).

The model is the common 12 parameters at the session's one temperature. The diagnosis tries
its library's candidates, g_sensitivity among them (the static faces, gravity along each
axis both ways, separate it from the bias); those one temperature and one turn per axis
cannot separate are listed as not identifiable."""

from ...fit.model import DEFAULT_TERMS
from ..registry import ProtocolDefaults, option_defaults

DEFAULTS: ProtocolDefaults = {
    "options": option_defaults("ferraris"),
    "model": {"terms": list(DEFAULT_TERMS)},
    "diagnosis": {"candidates": ["g_sensitivity"]},
}
