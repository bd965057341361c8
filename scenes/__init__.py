"""Runnable scenes (``python -m scenes.<name> --help``); see scenes/README.md."""
