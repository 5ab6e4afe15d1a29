"""Server settings and security helpers."""
