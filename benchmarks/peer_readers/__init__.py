"""Other tools' readers run on what we export, each in its own environment (never in CI)."""
