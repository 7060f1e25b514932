"""``python -m ncjax.cli``: the ``ncjax`` command."""

from .main import console_script

console_script()
