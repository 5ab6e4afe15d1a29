"""REST API: routers per resource (``server.api.routes``), dependencies in ``deps``."""
