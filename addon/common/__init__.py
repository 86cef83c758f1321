"""What every feature shares: the add-on preferences (``prefs``), panel helpers (``ui_common``) and the
job registry with its one modal follower (``jobs``). Registered first, unregistered last."""
from . import jobs, prefs
from .registration import registrar

_MODULES = (prefs, jobs)

register, unregister = registrar(_MODULES)
