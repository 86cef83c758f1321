"""Compare feature: render a run's views and import them as image planes beside the scene."""


def register():
    pass


def unregister():
    pass
