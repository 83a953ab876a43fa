"""The ``graphcal`` command line.

:mod:`graphcal.cli.app` creates the typer app and registers the commands; each command is
a module of its own (``simulate``, ``calibrate``, ``noise``, ``fuse``, ``methods``,
``marginals``, ``compare``, ``import_asterix``, ``observability``, ``report``, ``correct``)
that imports only :mod:`graphcal.cli.common` (consoles, exit codes, error messages, progress
bar) and the lower layers of graphcal, the heavy ones inside the command function, so that
``graphcal --help`` starts at once.
"""
