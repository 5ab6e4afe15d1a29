"""Submodules of the ``associate`` stage: detection preparation, the 3D multi-person tracker,
identity selection and the human edit overlay."""
