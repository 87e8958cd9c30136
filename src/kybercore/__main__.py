"""``python -m kybercore`` is the ``kybercore`` command."""

from kybercore.cli.main import app

app()
