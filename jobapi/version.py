"""The one version of matforge.

``pyproject.toml`` reads it from here (``[tool.setuptools.dynamic]``), and so do
``matforge.__version__``, ``matforge --version``, the OpenAPI document of the REST API and
every job manifest (``matforge_version``). It lives in :mod:`jobapi`, the lowest layer the
service and the kinds share, so that every layer can read it without importing ``matforge``
(the public API is the topmost layer: nothing internal imports it).
"""

__version__ = "0.1.0"
