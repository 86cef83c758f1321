"""Train feature: the Train panel, its settings (``train_props``) and the training job."""
from .train_ui import register, unregister  # noqa: F401
