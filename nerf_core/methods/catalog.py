"""The built-in methods. Importing this module registers them with ``base.register``."""
