"""What every feature shares: the add-on preferences (``prefs``), panel helpers (``ui_common``) and the
job registry with its one modal follower (``jobs``). Registered first, unregistered last."""
from . import jobs, prefs

_MODULES = (prefs, jobs)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
