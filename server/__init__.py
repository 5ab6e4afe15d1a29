"""cornerman server: FastAPI + SQLite for sessions, jobs, identities and annotations.

Importing this package stays light (no torch / mujoco / onnxruntime): the pipeline
runs in worker processes (``server.jobs``), never in a request handler.
"""
