"""The ``georef`` commands, one a module: each is the command's options and a short body that hands the work to
``georef`` (its checks in :func:`georef.pipeline.preflight`) and prints the result. :mod:`georef_cli.main`
registers them."""
