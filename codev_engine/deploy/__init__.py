"""Deploy a law: export it as code (C99, Python) with a certified worst-case cost.

``bst.py`` builds the binary search tree over the law's regions, ``export.py`` plans an
export (tree or sequential search, its cost) and writes it, ``c_code.py`` and
``python_code.py`` hold the writers.
"""

from codev_engine.deploy.export import export_c, export_python

__all__ = ["export_c", "export_python"]
