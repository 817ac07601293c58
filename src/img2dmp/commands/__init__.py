"""Subcommands of the ``img2dmp`` CLI, one module each (see :mod:`img2dmp.cli`)."""
