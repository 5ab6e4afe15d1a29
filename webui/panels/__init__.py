"""GUI panels: each built by ``make_<panel>(server, ...) -> <Panel>Handles``; callbacks live in ``webui.app``."""
