"""Command-line entry points (``python scripts/NAME.py`` or ``python -m scripts.NAME``)."""
