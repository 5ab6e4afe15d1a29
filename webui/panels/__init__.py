"""GUI panels: each built by ``make_<panel>(scope, ...) -> <Panel>Handles`` on the server or on one client; callbacks live in ``webui.client_view``."""
