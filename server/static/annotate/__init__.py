"""The annotate page: its HTML template, edit controls, script and stylesheet (``server.api.routes.annotate``)."""
