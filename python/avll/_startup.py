"""Imported first by ``import avll``: in the ``avll`` command's own process, a Ctrl-C
while the package imports ends it with one line and exit code 130
(:func:`avll._sigint.at_startup`); anywhere else it does nothing."""

from ._sigint import at_startup

at_startup()
