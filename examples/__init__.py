"""The bundled example specs and notebook, installed as the package ``workbench.examples``.

A package so that a wheel (and an editable install) carries them: ``codev examples DIR``
writes them out (workbench/bundled.py). The files themselves are read here, at
``examples/``, by the README, the tests and the docs.
"""
