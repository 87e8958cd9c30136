"""``python -m kybercore`` is the ``kybercore`` command."""

from kybercore.cli import app

app()
